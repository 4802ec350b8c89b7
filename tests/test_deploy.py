"""deploy/: the systemd unit (verify, security exposure), the udev rule, and install.sh in a
temporary root (DESTDIR-style: files laid out, system commands only printed)."""

from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
import tempfile
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from daemon.config import (
    DEPRECATED_SECTIONS,
    HoldCheckSettings,
    JobSettings,
    RequestSettings,
    Settings,
    WatchSettings,
)
from daemon.sampler.config import SamplerConfig
from drivers import ROBOT_KINDS, AsciiIndicatorConfig, IndicatorConfig
from drivers.indicator import RegisterMap
from drivers.modbus_robot import JointRegisterMap

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy"
UNIT = DEPLOY / "cablecal.service"
RULE = DEPLOY / "99-cablecal.rules"
INSTALL = DEPLOY / "install.sh"
EXAMPLE = DEPLOY / "cablecal.toml.example"
EXEC_START = "/opt/cablecal/venv/bin/cablecal serve --config /etc/cablecal/cablecal.toml"
MAX_EXPOSURE = 3.0

SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
needs_systemd_analyze = pytest.mark.skipif(
    SYSTEMD_ANALYZE is None,
    reason="systemd-analyze is not installed (package systemd; .ci/run installs it)",
)


def directives(path: Path) -> dict[str, list[str]]:
    """``{"Section.Key": [values in order]}`` of a unit file (repeated keys accumulate)."""
    out: dict[str, list[str]] = {}
    section = ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        out.setdefault(f"{section}.{key.strip()}", []).append(value.strip())
    return out


def runnable_copy(tmp_path: Path, extra: str = "") -> Path:
    """The unit with ExecStart's binary replaced by one that exists on this machine (the
    venv path does not, and verify rightly complains about that)."""
    text = UNIT.read_text()
    assert text.count(f"ExecStart={EXEC_START}") == 1
    true = shutil.which("true") or "/bin/true"
    text = text.replace("ExecStart=/opt/cablecal/venv/bin/cablecal", f"ExecStart={true}")
    copy = tmp_path / "cablecal.service"
    copy.write_text(text + extra)
    return copy


# --- the unit ----------------------------------------------------------------------------


def test_unit_has_the_required_settings() -> None:
    d = directives(UNIT)

    def one(key: str) -> str:
        assert len(d.get(key, [])) == 1, f"{key}: expected exactly one, got {d.get(key)}"
        return d[key][0]

    assert one("Service.Type") == "notify"
    assert one("Service.NotifyAccess") == "main"
    assert int(one("Service.WatchdogSec")) == 30
    assert one("Service.Restart") == "on-failure"
    assert float(one("Service.RestartSec")) > 0
    assert (one("Service.User"), one("Service.Group")) == ("cablecal", "cablecal")
    assert one("Service.SupplementaryGroups") == "dialout"
    assert one("Service.StateDirectory") == "cablecal"
    assert one("Service.ConfigurationDirectory") == "cablecal"
    assert one("Service.ExecStart") == EXEC_START
    assert one("Service.Environment") == "CABLECAL_STATE_DIR=%S/cablecal"
    assert one("Service.EnvironmentFile") == "-/etc/cablecal/env"
    assert one("Service.ProtectSystem") == "strict"
    assert one("Service.ProtectHome") == "yes"
    assert one("Service.NoNewPrivileges") == "yes"
    assert one("Service.PrivateTmp") == "yes"
    assert one("Service.CapabilityBoundingSet") == ""
    assert set(one("Service.RestrictAddressFamilies").split()) == {"AF_UNIX", "AF_INET", "AF_INET6"}
    assert one("Service.SystemCallArchitectures") == "native"
    assert d["Service.SystemCallFilter"][0] == "@system-service"
    # Serial access through the device cgroup, not PrivateDevices= (which hides ttyUSB).
    assert one("Service.DevicePolicy") == "closed"
    assert sorted(d["Service.DeviceAllow"]) == ["char-ttyACM rw", "char-ttyUSB rw"]
    assert "Service.PrivateDevices" not in d
    assert one("Install.WantedBy") == "multi-user.target"


def _bytes(value: str) -> int:
    """A systemd memory size (``2G``, ``512M``, bytes) in bytes."""
    units = {"K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}
    if value[-1:].upper() in units:
        return int(float(value[:-1]) * units[value[-1].upper()])
    return int(value)


def test_unit_bounds_the_memory_with_its_reason() -> None:
    """MemoryHigh= (throttle) below MemoryMax= (the OOM killer), both above what the daemon
    and its workers need at the default [requests] and [jobs] settings, and the reason
    written beside them."""
    d = directives(UNIT)
    high, top = _bytes(d["Service.MemoryHigh"][0]), _bytes(d["Service.MemoryMax"][0])
    assert len(d["Service.MemoryHigh"]) == len(d["Service.MemoryMax"]) == 1
    assert 1024**3 <= high < top <= 8 * 1024**3
    text = UNIT.read_text()
    comment = text[: text.index("\nMemoryHigh=")].rsplit("\n\n", 1)[-1]
    assert "OOM" in comment and "max_filters" in comment, comment


@needs_systemd_analyze
def test_unit_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    unit = runnable_copy(tmp_path)
    proc = subprocess.run(
        [str(SYSTEMD_ANALYZE), "verify", str(unit)], capture_output=True, text=True, timeout=60
    )
    output = proc.stdout + proc.stderr
    ours = [line for line in output.splitlines() if "cablecal" in line]
    assert proc.returncode == 0, output
    assert ours == [], "systemd-analyze verify complains about the unit:\n" + "\n".join(ours)


@needs_systemd_analyze
def test_verify_would_catch_a_bad_directive(tmp_path: Path) -> None:
    """The check above is not vacuous: a misspelt directive is reported on our unit's lines."""
    unit = runnable_copy(tmp_path, extra="\n[Service]\nPrivateDevice=yes\n")
    proc = subprocess.run(
        [str(SYSTEMD_ANALYZE), "verify", str(unit)], capture_output=True, text=True, timeout=60
    )
    assert "cablecal.service" in proc.stdout + proc.stderr
    assert "PrivateDevice" in proc.stdout + proc.stderr


@needs_systemd_analyze
def test_security_exposure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], record_property: pytest.RecordProperty
) -> None:
    proc = subprocess.run(
        [str(SYSTEMD_ANALYZE), "security", "--offline=true", str(runnable_copy(tmp_path))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output  # --offline needs systemd >= 250
    match = re.search(r"Overall exposure level for cablecal\.service: (\d+(?:\.\d+)?)", output)
    assert match, output
    exposure = float(match.group(1))
    record_property("systemd_security_exposure", exposure)
    with capsys.disabled():
        print(f"\nsystemd-analyze security exposure of cablecal.service: {exposure}")
    assert exposure <= MAX_EXPOSURE, output


# --- the udev rule -----------------------------------------------------------------------

_RULE_TOKEN = re.compile(
    r'^(?P<key>[A-Z_]+(?:\{[A-Za-z_]+\})?)(?P<op>==|!=|\+=|-=|:=|=)"(?P<value>[^"]*)"$'
)


def rule_lines(path: Path) -> list[list[tuple[str, str, str]]]:
    rules = []
    for raw in path.read_text().splitlines():
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        tokens = []
        for token in raw.split(", "):
            m = _RULE_TOKEN.match(token.strip())
            assert m, f"malformed udev token {token!r} in: {raw}"
            tokens.append((m["key"], m["op"], m["value"]))
        rules.append(tokens)
    return rules


def test_udev_rule() -> None:
    rules = rule_lines(RULE)
    ids = set()
    for tokens in rules:
        assert ("SUBSYSTEM", "==", "tty") in tokens
        assert ("SYMLINK", "+=", "cablecal-indicator") in tokens
        assert ("GROUP", "=", "dialout") in tokens
        assert ("MODE", "=", "0660") in tokens
        values = {k: v for k, op, v in tokens if op == "=="}
        ids.add((values["ATTRS{idVendor}"], values["ATTRS{idProduct}"]))
    assert ids == {("0403", "6001"), ("1a86", "7523")}  # FTDI FT232R, WCH CH340
    text = RULE.read_text()
    for doc in ("udevadm info -a -n /dev/ttyUSB0", "lsusb", "ATTRS{serial}", "udevadm control"):
        assert doc in text


@pytest.mark.skipif(
    subprocess.run(["udevadm", "verify", "--help"], capture_output=True).returncode != 0
    if shutil.which("udevadm")
    else True,
    reason="udevadm verify needs systemd >= 253",
)
def test_udev_rule_passes_udevadm_verify() -> None:
    proc = subprocess.run(["udevadm", "verify", str(RULE)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


# --- install.sh in a temporary root ------------------------------------------------------


def run_install(destdir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    cmd = ["bash", str(INSTALL), "--destdir", str(destdir), "--no-pip", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60)


def snapshot(root: Path) -> dict[str, tuple[int, bytes]]:
    return {
        str(p.relative_to(root)): (p.stat().st_mode, p.read_bytes() if p.is_file() else b"")
        for p in sorted(root.rglob("*"))
    }


@pytest.fixture
def destdir(tmp_path: Path) -> Path:
    root = tmp_path / "root"
    root.mkdir()
    return root


def test_install_lays_down_the_files(destdir: Path) -> None:
    proc = run_install(destdir)
    assert proc.returncode == 0, proc.stderr
    etc = destdir / "etc"
    assert (etc / "systemd/system/cablecal.service").read_bytes() == UNIT.read_bytes()
    assert (etc / "udev/rules.d/99-cablecal.rules").read_bytes() == RULE.read_bytes()
    assert (etc / "cablecal/cablecal.toml").read_bytes() == EXAMPLE.read_bytes()
    assert (etc / "cablecal/cablecal.toml.example").read_bytes() == EXAMPLE.read_bytes()
    env = (etc / "cablecal/env").read_text()
    assert re.search(r"^CABLECAL_API_TOKEN=[0-9a-f]{64}$", env, re.MULTILINE), env
    modes = {
        "etc/systemd/system/cablecal.service": 0o644,
        "etc/udev/rules.d/99-cablecal.rules": 0o644,
        "etc/cablecal": 0o755,
        "etc/cablecal/cablecal.toml": 0o640,
        "etc/cablecal/env": 0o640,
    }
    for rel, mode in modes.items():
        assert stat.S_IMODE((destdir / rel).stat().st_mode) == mode, rel
    assert (destdir / "opt/cablecal").is_dir()
    assert not (destdir / "opt/cablecal/venv").exists()  # --no-pip
    assert not (destdir / "var").exists()  # the state directory is systemd's
    # System commands are printed, not run (and none of them ran on this machine).
    out = proc.stdout
    assert re.search(r"^would run: (useradd|usermod) .*cablecal$", out, re.MULTILINE), out
    for cmd in (
        "chown root:cablecal " + str(etc / "cablecal/env"),
        "systemctl daemon-reload",
        "udevadm control --reload",
        "udevadm trigger --action=change --subsystem-match=tty",
        "systemctl enable cablecal.service",
        "systemctl restart cablecal.service",
    ):
        assert f"would run: {cmd}\n" in out, cmd


def test_install_twice_is_idempotent(destdir: Path) -> None:
    assert run_install(destdir).returncode == 0
    first = snapshot(destdir)
    proc = run_install(destdir)
    assert proc.returncode == 0, proc.stderr
    assert snapshot(destdir) == first  # same files, same modes, same token
    assert "keeping the existing /etc/cablecal/cablecal.toml" in proc.stdout


def test_upgrade_keeps_config_token_and_database(destdir: Path) -> None:
    conf = destdir / "etc/cablecal/cablecal.toml"
    env = destdir / "etc/cablecal/env"
    db = destdir / "var/lib/cablecal/cablecal.sqlite3"
    for path, text in ((conf, "port = 9090\n"), (env, "CABLECAL_API_TOKEN=mine\n"), (db, "db")):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    db_stat = db.stat()
    old_example = destdir / "etc/cablecal/cablecal.toml.example"
    old_example.write_text("# from an older release\n")
    proc = run_install(destdir)
    assert proc.returncode == 0, proc.stderr
    assert conf.read_text() == "port = 9090\n"
    assert env.read_text() == "CABLECAL_API_TOKEN=mine\n"
    assert db.read_text() == "db" and db.stat().st_mtime_ns == db_stat.st_mtime_ns
    assert sorted(p.name for p in db.parent.iterdir()) == ["cablecal.sqlite3"]
    assert old_example.read_bytes() == EXAMPLE.read_bytes()  # the reference is refreshed


def test_uninstall_keeps_database_and_config(destdir: Path) -> None:
    assert run_install(destdir).returncode == 0
    db = destdir / "var/lib/cablecal/cablecal.sqlite3"
    db.parent.mkdir(parents=True)
    db.write_text("db")
    proc = run_install(destdir, "--uninstall")
    assert proc.returncode == 0, proc.stderr
    assert "would run: systemctl disable --now cablecal.service\n" in proc.stdout
    assert not (destdir / "etc/systemd/system/cablecal.service").exists()
    assert not (destdir / "etc/udev/rules.d/99-cablecal.rules").exists()
    assert not (destdir / "opt/cablecal").exists()
    assert db.read_text() == "db"
    assert (destdir / "etc/cablecal/cablecal.toml").exists()
    assert (destdir / "etc/cablecal/env").exists()
    # Uninstalling again is harmless.
    assert run_install(destdir, "--uninstall").returncode == 0


def test_purge_removes_database_and_config(destdir: Path) -> None:
    assert run_install(destdir).returncode == 0
    (destdir / "var/lib/cablecal").mkdir(parents=True)
    proc = run_install(destdir, "--purge")
    assert proc.returncode == 0, proc.stderr
    assert not (destdir / "var/lib/cablecal").exists()
    assert not (destdir / "etc/cablecal").exists()
    assert not (destdir / "etc/systemd/system/cablecal.service").exists()


@pytest.fixture
def script_for_nobody() -> Iterator[list[str]]:
    """A command prefix that runs install.sh as an unprivileged user: as is when the tests do
    not run as root, else through setpriv as nobody (a copy of the tree it can read)."""
    if os.geteuid() != 0:
        yield ["bash", str(INSTALL)]
        return
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root and setpriv (util-linux) is missing")
    with tempfile.TemporaryDirectory(prefix="cc-install-") as d:
        tree = Path(d)
        shutil.copytree(DEPLOY, tree / "deploy")
        shutil.copy(ROOT / "pyproject.toml", tree)
        for p in [tree, *tree.rglob("*")]:
            p.chmod(0o755 if p.is_dir() else 0o644)
        nobody = ["--reuid=65534", "--regid=65534", "--clear-groups"]
        yield [setpriv, *nobody, "bash", str(tree / "deploy/install.sh")]


def test_refuses_to_run_without_root(script_for_nobody: list[str]) -> None:
    proc = subprocess.run(script_for_nobody, capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    assert "must run as root" in proc.stderr
    assert "would run" not in proc.stdout


@pytest.mark.parametrize(("destdir", "error"), [("relative/root", "absolute"), ("/", "real")])
def test_rejects_bad_destdir(script_for_nobody: list[str], destdir: str, error: str) -> None:
    proc = subprocess.run(
        [*script_for_nobody, "--destdir", destdir, "--no-pip"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tempfile.gettempdir(),
    )
    assert proc.returncode != 0
    assert error in proc.stderr


def test_script_syntax_and_shellcheck() -> None:
    assert subprocess.run(["bash", "-n", str(INSTALL)]).returncode == 0
    assert os.access(INSTALL, os.X_OK)
    if shutil.which("shellcheck"):
        proc = subprocess.run(["shellcheck", str(INSTALL)], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stdout


# --- cablecal.toml.example against daemon.config.Settings --------------------------------

_HEADER = re.compile(r"^#?\[(?P<section>[a-z_.]+)\]")
_SETTING = re.compile(r"^#?(?P<key>[a-z_]+) *=")


@dataclass
class Block:
    """One table of the example with its sub-tables (an alternative starts a new one)."""

    section: str
    kind: str | None = None
    values: dict[str, Any] = field(default_factory=dict)
    # (sub-table or "", key, value, inline comment) of every setting line
    lines: list[tuple[str, str, Any, str]] = field(default_factory=list)


def example_blocks() -> list[Block]:
    """Every setting line of the example, commented out ("#key = ...") or not."""
    blocks = [Block("")]
    sub = ""
    for line in EXAMPLE.read_text().splitlines():
        if m := _HEADER.match(line):
            top, _, sub = m["section"].partition(".")
            if not sub:
                blocks.append(Block(top))
            continue
        if not (m := _SETTING.match(line)):
            continue
        body = line.removeprefix("#")
        value = tomllib.loads(body)[m["key"]]  # also proves each line is valid TOML
        comment = body.split("#", 1)[1] if "#" in body else ""
        block = blocks[-1]
        if m["key"] == "kind" and not sub:
            block.kind = value
        target = block.values.setdefault(sub, {}) if sub else block.values
        target[m["key"]] = value
        block.lines.append((sub, m["key"], value, comment))
    return blocks


def block_models(block: Block, defaults: Settings) -> dict[str, BaseModel]:
    """The model instance holding the defaults of each (sub-)table of ``block``."""
    kind = block.kind
    if block.section == "":
        return {"": defaults}
    if block.section in ("sampler", "jobs", "requests", "hold_check", "watch"):
        return {"": getattr(defaults, block.section)}
    if block.section == "indicator":
        main: BaseModel = {
            "modbus-rtu": defaults.indicator,  # port: the udev rule's /dev/cablecal-indicator
            "modbus-tcp": IndicatorConfig(kind="modbus-tcp"),
            "ascii": AsciiIndicatorConfig(),
        }[kind or "modbus-rtu"]
        return {"": main, "registers": RegisterMap()}
    if block.section == "robot":
        kind = kind or "manual"
        main = defaults.robot if kind == "manual" else ROBOT_KINDS[kind].config()
        return {"": main, "registers": JointRegisterMap()}
    raise AssertionError(f"unexpected table [{block.section}] in the example")


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in list(os.environ):
        if name.startswith("CABLECAL_") or name == "STATE_DIRECTORY":
            monkeypatch.delenv(name)


@pytest.mark.usefixtures("clean_env")
def test_example_parses_to_the_defaults() -> None:
    loaded = Settings.load(EXAMPLE)
    assert loaded.model_dump() == Settings().model_dump()


@pytest.mark.usefixtures("clean_env")
def test_example_shows_the_defaults_with_units() -> None:
    """Every "#key = value" shows the model's default, unless its comment says "default:"
    (then the value is an example and the comment states the default); every setting line
    has a comment."""
    defaults = Settings()
    for block in example_blocks():
        models = block_models(block, defaults)
        for sub, key, value, comment in block.lines:
            where = f"[{block.section}{'.' + sub if sub else ''}] {key} (kind {block.kind})"
            assert comment.strip() or key == "kind", f"{where}: no comment (unit, meaning)"
            if "default:" in comment:
                continue
            expected = getattr(models[sub], key)
            assert value == expected, f"{where}: example shows {value!r}, default {expected!r}"


@pytest.mark.usefixtures("clean_env")
def test_example_mentions_every_setting() -> None:
    blocks = example_blocks()
    seen: dict[tuple[str, str], set[str]] = {}
    for block in blocks:
        for sub, key, _, _ in block.lines:
            seen.setdefault((block.section, sub), set()).add(key)
        seen.setdefault((block.section, "kinds"), set()).add(str(block.kind))

    def keys(model: type[BaseModel]) -> set[str]:
        return set(model.model_fields)

    tables = {"sampler", "jobs", "requests", "hold_check", "watch", "indicator", "robot"}
    expected = {
        ("", ""): keys(Settings) - tables - set(DEPRECATED_SECTIONS),
        ("sampler", ""): keys(SamplerConfig),
        ("jobs", ""): keys(JobSettings),
        ("requests", ""): keys(RequestSettings),
        ("hold_check", ""): keys(HoldCheckSettings),
        ("watch", ""): keys(WatchSettings),
        ("indicator", ""): (keys(IndicatorConfig) | keys(AsciiIndicatorConfig)) - {"registers"},
        ("indicator", "registers"): keys(RegisterMap),
        ("robot", ""): set().union(*(keys(entry.config) for entry in ROBOT_KINDS.values()))
        - {"registers"},
        ("robot", "registers"): keys(JointRegisterMap),
    }
    for table, names in expected.items():
        missing = names - seen.get(table, set())
        assert not missing, f"{table}: the example does not mention {sorted(missing)}"
    assert seen[("indicator", "kinds")] >= {"modbus-rtu", "modbus-tcp", "ascii"}
    assert seen[("robot", "kinds")] >= set(ROBOT_KINDS)


@pytest.mark.usefixtures("clean_env")
def test_example_alternatives_are_valid() -> None:
    """Each table, with all its lines uncommented, is a valid configuration."""
    for block in example_blocks():
        if block.section == "":
            Settings(**block.values)
        else:
            Settings(**{block.section: block.values})
