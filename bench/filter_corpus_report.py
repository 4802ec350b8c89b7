"""bench/filter_corpus.md from bench/filter_corpus.json (bench/filter_corpus.py)."""

from __future__ import annotations

from typing import Any

LANGS = ("rapid", "krl", "fanuc", "urscript")
#: How to read the columns (definitions, not figures).
NOTES = """## How to read it

- Programs (b) and (c) count **per program**: a program passes when every corrected target
  passes. "(b) shift/turn": the largest error of a corrected target against the exact
  expected value, as read back from the output text by the dialect's own parser.
- "(c) corrected / reachable": of the targets (a) corrected (the nominal controller reaches
  them on their written configuration, as the filter reads it), those (c) corrects: the
  acceptance's bar is 95 %. "(c) corrected / used": of every target a move uses that is the
  arm's own (not on a track or positioner, not a position register, not in `$config.dat`,
  not unused): this also counts targets whose tool or base the filter cannot resolve and
  targets it finds no nominal solution for (the last column; on lab cells whose arm is
  assumed these are not proven unreachable).
- "(a) left: no nominal solution": targets the nominal model finds no solution for on the
  written configuration (an assumed arm, a target out of reach, or a misread rule).
"""


def _ok_a(r: dict[str, Any]) -> bool:
    a = r["a"]
    if not r.get("valid", True):
        return a["exit"] == 2 and not a["traceback"]
    return a["exit"] in (0, 3) and not a["traceback"] and a["identical"]


def _ok_b(b: dict[str, Any]) -> bool:
    return b["exit"] in (0, 3) and not b["traceback"] and not b.get("fails") and "error" not in b


def _ok_c(c: dict[str, Any]) -> bool:
    share = c.get("share")
    return (
        not c["traceback"]
        and "error" not in c
        and (share is None or share >= 0.95)
        and c["skeleton_changed"] == 0
        and c["numbers_changed_elsewhere"] == 0
        and c["config_dat_identical"]
    )


def _ok_d(d: dict[str, Any]) -> bool:
    return all(v["exit"] == 2 and not v["traceback"] for v in d.values())


def _old_cell(r: dict[str, Any]) -> str:
    o = r.get("a_old_file")
    if o is None:
        return "–"
    same = "yes" if o["identical"] else "**no**"
    return f"{o['exit']}{' traceback' if o['traceback'] else ''}, {same}"


def _b_cell(b: dict[str, Any]) -> str:
    if "error" in b:
        return f"exit {b['exit']} {'traceback' if b['traceback'] else ''}"
    mark = "ok" if _ok_b(b) else f"**{len(b['fails'])} fail**"
    return f"{mark}: {b['corrected']} corr., {b['max_mm']:.4f} mm, {b['max_deg']:.4f}°"


def _c_cell(c: dict[str, Any]) -> str:
    if "error" in c:
        return f"exit {c['exit']} {'traceback' if c['traceback'] else ''}"
    share = "–" if c["share"] is None else f"{100 * c['share']:.1f} %"
    mark = "ok" if _ok_c(c) else "**fail**"
    extra = ""
    if c["skeleton_changed"] or c["numbers_changed_elsewhere"]:
        extra = f", tokens {c['skeleton_changed']}/{c['numbers_changed_elsewhere']}"
    if not c["config_dat_identical"]:
        extra += ", $config.dat changed"
    return f"{mark}: {c['corrected_of_reachable']}/{c['reachable_a']} = {share}{extra}"


def _d_cell(d: dict[str, Any]) -> str:
    return " ".join(
        f"{v['exit']}{'!' if v['traceback'] else ''}"
        for v in (d["unknown_only"], d["other_dialect"], d["empty"])
    )


def _no_solution(r: dict[str, Any]) -> int:
    """Targets (a) left as having no nominal solution: outside (c)'s denominator, and not
    proven unreachable (the arm of a lab cell is assumed; a misread rule looks the same)."""
    return sum(n for k, n in r["a"]["left_by_reason"].items() if "no nominal solution" in k)


def markdown(doc: dict[str, Any]) -> str:
    progs = doc["programs"]
    lines = [
        "# `cablecal filter` on real programs: issue 34's acceptance, measured",
        "",
        f"Code under test: main at `{doc['commit'] or 'an archive (see the findings)'}` "
        "(the bench's branch adds only bench files). "
        "Fetch (outside the repository): `PYTHONPATH=. python -m bench.filter_corpus fetch "
        "/work/corpus --mirrors DIR` (DIR holds a git clone per repository, `OWNER+NAME/repo`). "
        "Run: `PYTHONPATH=. python -m bench.filter_corpus run /work/corpus` "
        "(bench/filter_corpus.py says what each check does and how to fetch the programs; "
        "bench/filter_corpus_manifest.py names every program: repository, commit, paths, arm).",
        "",
        "Columns: **targets** found; **(a)** calibration = nominal: exit, files "
        "byte-identical; **(a) old file**: the same with the arm as a model file without its "
        "`[controller]` table (the format before issue 34); **(b)** d1 + 0.3 mm and "
        "θ1 + 0.05°: corrected targets read back from "
        "the output and compared with the exact expected target (largest error in mm and "
        "deg); **(c)** realistic calibration: corrected of the targets (a) found reachable "
        "(bar 95 %), token streams and `$config.dat`; **(d)** exit of unknown `--only`, "
        "another dialect's text, an empty file (bar: 2 2 2; `!` = a traceback).",
        "",
        "| program | lang | arm | targets | (a) exit, identical | (a) old file | (b) shift "
        "| (b) turn | (c) realistic | (d) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in progs:
        if "bench_error" in r:
            lines.append(
                f"| {r['id']} | {r['language']} | | | bench error: {r['bench_error']} |||||"
            )
            continue
        a = r["a"]
        a_cell = f"{a['exit']}{' traceback' if a['traceback'] else ''}, " + (
            "yes" if a["identical"] else f"**no: {', '.join(a['not_identical'])}**"
        )
        if r.get("valid", True):
            bc = f"{_b_cell(r['b_shift'])} | {_b_cell(r['b_turn'])} | {_c_cell(r['c'])}"
        else:
            a_cell += " (not loadable: 2 expected)"
            bc = "– | – | –"
        lines.append(
            f"| {r['id']} | {r['language']} | {r['arm']} | {r['targets']} | {a_cell} "
            f"| {_old_cell(r)} | {bc} | {_d_cell(r['d'])} |"
        )
    lines += ["", "## Per language", ""]
    lines += [
        "| language | programs | targets | (a) pass | (b) shift pass | (b) turn pass "
        "| (c) pass | (c) corrected / reachable | (c) corrected / used | (d) pass "
        "| (a) left: no nominal solution |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for lang in LANGS:
        rs = [r for r in progs if r["language"] == lang and "bench_error" not in r]
        if not rs:
            continue
        vs = [r for r in rs if r.get("valid", True)]
        cc = sum(r["c"].get("corrected_of_reachable", 0) for r in rs)
        uc = sum(r["c"].get("corrected_of_used", 0) for r in rs)
        un = sum(r["c"].get("used", 0) for r in rs)
        cr = sum(r["c"].get("reachable_a", 0) for r in rs)
        lines.append(
            f"| {lang} | {len(rs)} | {sum(r['targets'] for r in rs)} "
            f"| {sum(_ok_a(r) for r in rs)} | {sum(_ok_b(r['b_shift']) for r in vs)} "
            f"| {sum(_ok_b(r['b_turn']) for r in vs)} | {sum(_ok_c(r['c']) for r in vs)} "
            f"| {cc} / {cr}{f' = {100 * cc / cr:.1f} %' if cr else ''} "
            f"| {uc} / {un}{f' = {100 * uc / un:.1f} %' if un else ''} "
            f"| {sum(_ok_d(r['d']) for r in rs)} | {sum(_no_solution(r) for r in rs)} |"
        )
    lines += ["", "## Why targets are left at (a) (nominal calibration)", ""]
    for r in progs:
        if "bench_error" in r:
            continue
        g = r["a"]["left_by_reason"]
        if g or r["a"]["errors"]:
            items = "; ".join(f"{n} × {k}" for k, n in list(g.items())[:6])
            errs = "; ".join(e["message"][:160] for e in r["a"]["errors"][:3])
            lines.append(f"- **{r['id']}**: {items}{' — errors: ' + errs if errs else ''}")
    lines += ["", "## Failures", ""]
    for r in progs:
        if "bench_error" in r:
            lines.append(f"- **{r['id']}**: the bench failed: {r['bench_error']}")
            continue
        out = failures(r)
        lines += [f"- **{r['id']}** {x}" for x in out]
    lines += ["", NOTES]
    return "\n".join(lines) + "\n"


def failures(r: dict[str, Any]) -> list[str]:
    out: list[str] = []
    a = r["a"]
    if a["traceback"]:
        out.append(f"(a): traceback: `{a['traceback'][-200:]}`")
    elif not r.get("valid", True):
        if a["exit"] != 2:
            out.append(f"(a): exit {a['exit']} for a file the controller cannot load (expected 2)")
        return out
    elif a["exit"] not in (0, 3):
        out.append(f"(a): exit {a['exit']} (expected 0 or 3): {a['tail'][-200:]!r}")
    if not a["identical"]:
        out.append(f"(a): output not byte-identical: {', '.join(a['not_identical'])}")
    for tag in ("b_shift", "b_turn"):
        b = r[tag]
        if "error" in b:
            out.append(f"({tag}): exit {b['exit']}: {b['error'][-200:]!r}")
            continue
        for f in b["fails"][:5]:
            out.append(f"({tag}): {f}")
        if len(b["fails"]) > 5:
            out.append(f"({tag}): … {len(b['fails']) - 5} more")
    c = r["c"]
    if "error" in c:
        out.append(f"(c): exit {c['exit']}: {c['error'][-200:]!r}")
    elif not _ok_c(c):
        out.append(
            f"(c): corrected {c['corrected_of_reachable']} of {c['reachable_a']} reachable; "
            f"left: {c['left_reachable']}; tokens changed outside numbers "
            f"{c['skeleton_changed']}, numbers off target lines {c['numbers_changed_elsewhere']}, "
            f"$config.dat identical {c['config_dat_identical']}"
        )
    for tag, v in r["d"].items():
        if v["exit"] != 2 or v["traceback"]:
            tb = " with a traceback" if v["traceback"] else ""
            out.append(f"(d) {tag}: exit {v['exit']}{tb} (expected 2): {v['tail'][-160:]!r}")
    return out
