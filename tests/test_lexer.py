"""The one lexer of the controller languages (calib.programs.lexer)."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from calib.programs import lexer
from calib.programs.lexer import FANUC, KRL, LEXICONS, RAPID, URSCRIPT

ROOT = Path(__file__).resolve().parents[1]
PROGRAMS = ROOT / "calib" / "programs"


def test_blank_keeps_length_and_line_ends_and_hides_comments_and_strings() -> None:
    text = 'MoveL p1, v100, z1, tool0; ! go "there"\r\nTPWrite "a ! b";\n'
    out = RAPID.blank(text)
    assert len(out) == len(text)
    assert [i for i, c in enumerate(out) if c in "\r\n"] == [
        i for i, c in enumerate(text) if c in "\r\n"
    ]
    assert "go" not in out and "there" not in out and "a ! b" not in out
    assert out.startswith("MoveL p1, v100, z1, tool0;") and "TPWrite" in out


def test_a_marker_in_a_string_is_no_comment_and_a_quote_in_a_comment_no_string() -> None:
    assert KRL.blank('X "a;b" Y ; c "d\nZ') == "X       Y       \nZ"
    assert URSCRIPT.blank("s = 'it\\'s # no' # yes\nq") == "s =" + " " * 19 + "\nq"


def test_urscript_escape_runs_to_the_closing_quote_and_an_unclosed_string_to_the_line_end() -> None:
    assert URSCRIPT.blank('a "x\\"y" b') == "a        b"
    assert URSCRIPT.blank('a "open\nb') == "a      \nb"


def test_random_text_blanks_to_the_same_shape_in_every_language() -> None:
    rng = random.Random(7)
    alphabet = "ab1.;!#/\"'\\\r\n [](){}"
    for _ in range(2000):
        text = "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 40)))
        for lex in LEXICONS.values():
            out = lex.blank(text)
            assert len(out) == len(text)
            assert all(o == t or o == " " for o, t in zip(out, text, strict=True))
            assert all(o == t for o, t in zip(out, text, strict=True) if t in "\r\n")


def test_code_of_and_comment_of() -> None:
    assert KRL.code_of('PTP {A1 0} ; "note"') == "PTP {A1 0} "
    assert KRL.code_of('MSG "a;b" ; c') == 'MSG "a;b" '
    assert RAPID.comment_of("   ! made by cablecal  ") == "made by cablecal"
    assert RAPID.comment_of("MoveAbsJ jt1; ! x") is None
    assert FANUC.comment_of("// 1: J P[1] ;") == "1: J P[1] ;"


@pytest.mark.parametrize(
    ("text", "ok"),
    [("1", True), ("-1.5", True), (".25", True), ("+3.", True), ("1E+09", True)],
)
def test_number_pattern(text: str, ok: bool) -> None:
    assert lexer.is_number(text) is ok
    assert not lexer.is_number("1.2.3") and not lexer.is_number("e5") and not lexer.is_number("")


def test_number_value_bounds_and_names_the_text() -> None:
    assert lexer.number_value("12.5", ValueError) == 12.5
    with pytest.raises(ValueError, match="9E999"):
        lexer.number_value("9E999", ValueError)
    with pytest.raises(ValueError, match="41 characters"):
        lexer.number_value("1" * 41, ValueError)
    with pytest.raises(ValueError, match="2e16"):
        lexer.number_value("2e16", ValueError, max_abs=1e15)


def test_brackets() -> None:
    code = "f([1, (2, 3)], {a, b}), x"
    assert lexer.close_bracket(code, 1) == 22
    assert lexer.close_bracket(code, 2) == 13
    assert lexer.close_bracket("[[1]", 0) == -1
    assert [code[a:b] for a, b in lexer.split_top(code, 2, 21)] == ["[1, (2, 3)]", " {a, b}"]
    assert lexer.split_top("a,b", 0, 3) == [(0, 1), (2, 3)]
    assert lexer.find_top("a[;];b", ";", 0) == 4
    assert lexer.find_top("a[;]", ";", 0) == 4
    assert lexer.cuts_top("x\\A[\\B]\\C", "\\", 0, 9) == [1, 7]


def test_clean_comment_keeps_no_opener_of_any_language() -> None:
    out = lexer.clean_comment("a;b\"c'd{e}f\x1bg!#")
    assert out == "a_b_c_d_e_f_g!#"
    for lex in LEXICONS.values():
        assert not any(q in out for q in lex.quotes)


def test_no_reader_keeps_its_own_number_pattern() -> None:
    """The number pattern's text lives in the lexer alone."""
    pattern = lexer.NUMBER_PATTERN
    owners = [
        str(p.relative_to(ROOT))
        for p in PROGRAMS.rglob("*.py")
        if p.name != "lexer.py" and pattern in p.read_text(encoding="utf-8")
    ]
    assert owners == []
