"""Property-based fuzzing of the whole command line: every command, every option.

The commands and their options are read from the typer app itself, so a command or
option added later is fuzzed too. Each generated case starts from a small valid command
line and replaces one to three option values (or arguments) with hostile ones chosen by
the option's type: numbers that are zero, negative, NaN, infinite, beyond float64, not
numbers at all or 100 KB long; paths that are too long, in missing directories, FIFOs,
devices, directories, files that exist, unknown figure formats; names that do not exist.

Every case runs in-process (``bifid.cli.main``) with a time budget: a case still
computing when it runs out is interrupted as a user would (SIGINT), which must end in
the interrupted exit code with, under ``--json``, a JSON object saying so. Properties:

- the exit code is one of the documented 0, 2, 3, 4, 130;
- stderr has no traceback, no line longer than 1000 characters, exactly one
  ``bifid: error:`` line when the exit code is not 0 (none otherwise), and no
  "internal error";
- stdout holds nothing but one JSON object with ``complete`` under ``--json`` (nothing
  at all after a refusal, exit 2 or 4);
- no output is left corrupt: every dataset written loads, every model directory loads,
  and no temporary file is left behind.

``BIFID_FUZZ_EXAMPLES`` (default 40 per test, 5 tests) scales the run;
``BIFID_FUZZ_REPORT=FILE`` writes the outcome counts as JSON (``make bench`` does, for
``docs/reliability.md``).
"""

from __future__ import annotations

import collections
import contextlib
import io
import json
import os
import re
import signal
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bifid.cli import main
from bifid.data import (
    ForcedRecord,
    LCORecord,
    forced_dataset,
    lco_dataset,
    load_dataset,
    save_dataset,
)
from bifid.io import load_model

N_EXAMPLES = int(os.environ.get("BIFID_FUZZ_EXAMPLES", "40"))
BUDGET_S = float(os.environ.get("BIFID_FUZZ_BUDGET", "1.5"))  # per case, then SIGINT
DOCUMENTED = (0, 2, 3, 4, 130)
OUTCOMES: collections.Counter[str] = collections.Counter()
FUZZ = settings(
    max_examples=N_EXAMPLES,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=list(HealthCheck),
)


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module", autouse=True)
def _imported() -> None:
    """Every command and the libraries they import on first use, imported before any
    interruption can land inside an import: an import that Ctrl-C interrupts leaves its
    finished submodules in this process bound to a half-initialised parent (seen as
    ``matplotlib has no attribute get_data_path`` in every later case). A user's next
    command is a new process; these cases share one."""
    import matplotlib.pyplot  # noqa: F401

    from bifid.cli import load_commands

    load_commands()


def _lco_file(path: Path) -> Path:
    t = np.arange(400) / 200.0
    recs = [
        LCORecord(
            param=p,
            signals=np.column_stack([a * np.sin(2 * np.pi * t), a * np.cos(2 * np.pi * t)]),
            sample_rate=200.0,
            stable=s,
            frequency=2 * np.pi,
        )
        for p, a, s in ((0.1, 0.3, True), (0.2, 0.45, True), (-0.1, 0.2, False))
    ]
    save_dataset(lco_dataset(recs, ["u1", "u2"], "mu", "", "hopf"), path)
    return path


def _forced_file(path: Path) -> Path:
    t = np.arange(400) / 100.0
    recs = [
        ForcedRecord(
            omega=w,
            forcing=0.1,
            signals=np.column_stack([0.5 * np.cos(w * t), -0.5 * w * np.sin(w * t)]),
            sample_rate=100.0,
            stable=True,
            force=0.1 * np.cos(w * t),
        )
        for w in (0.9, 1.0, 1.1)
    ]
    save_dataset(forced_dataset(recs, ["x", "v"], "x", "duffing"), path)
    return path


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    """Valid inputs and hostile files shared by every case (never written by a case)."""
    d = tmp_path_factory.mktemp("fuzz-world")
    w = {
        "lco": _lco_file(d / "lco.nc"),
        "forced": _forced_file(d / "forced.nc"),
        "dir": d / "a_directory",
        "fifo": d / "fifo.nc",
        "empty": d / "empty.nc",
        "garbage": d / "garbage.nc",
        "csv": d / "ok.csv",
        "device": d / "null_device",
    }
    w["dir"].mkdir()
    (w["dir"] / "something").write_text("x")
    os.mkfifo(w["fifo"])
    w["empty"].write_bytes(b"")
    w["garbage"].write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 4)
    rows = ["record,param,stable,time,h"] + [
        f"{r},{0.1 * (r + 1)},1,{i / 100:.2f},{np.sin(2 * np.pi * i / 100):.6f}"
        for r in range(2)
        for i in range(200)
    ]
    w["csv"].write_text("\n".join(rows) + "\n")
    with contextlib.suppress(OSError):  # a private /dev/null twin; needs root
        os.mknod(w["device"], stat.S_IFCHR | 0o666, os.makedev(1, 3))
    return w


# ------------------------------------------------------------------ commands and options
def _commands() -> dict[str, Any]:
    """Every leaf command of the app, by its path ('fit hopf', 'continue', ...)."""
    import typer

    from bifid.cli import app, load_commands

    load_commands()
    out: dict[str, Any] = {}

    def walk(group, prefix: tuple[str, ...]) -> None:
        for name, cmd in group.commands.items():
            if hasattr(cmd, "commands"):
                walk(cmd, (*prefix, name))
            else:
                out[" ".join((*prefix, name))] = cmd

    walk(typer.main.get_command(app), ())
    return out


COMMANDS = _commands()
# small valid command lines; OUT / OUTDIR / PLOT are replaced per case
BASE: dict[str, list[str]] = {
    "systems": [],
    "continue": [
        "hopf",
        "--param",
        "mu",
        "--range",
        "-0.2",
        "0.2",
        "--mesh",
        "16",
        "--max-steps",
        "20",
    ],
    "frc": ["duffing", "--forcing", "0.1", "--omega-range", "0.9", "1.1", "--mesh", "16"],
    "scurve": ["duffing", "--omega", "1.0", "--forcing-range", "0.01", "0.2", "--mesh", "16"],
    "backbone": ["duffing", "--amplitude-range", "0.01", "0.5", "--mesh", "16"],
    "cbc": ["hopf", "--protocol", "ppcbc", "--values", "0.1", "--out", "OUT"],
    "fit hopf": ["LCO", "--out", "OUTDIR"],
    "fit forced": ["FORCED", "--out", "OUTDIR"],
    "fit mechanistic": ["LCO", "--model", "flutter", "--free", "ka2,ka3", "--out", "OUTDIR"],
    "predict": ["MODEL", "--range", "-0.2", "0.2"],
    "import": ["CSV", "--out", "OUT"],
    "demo": ["forced", "--out", "OUTDIR"],
}
LONG = "x" * 100_000
NUMBERS = [
    "0",
    "-0",
    "-1",
    "1e-320",
    "1e400",
    "-1e400",
    "nan",
    "inf",
    "-inf",
    "",
    " ",
    "abc",
    "1,5",
    "0x10",
    "9" * 400,
    LONG,
    "1e308",
    "٣",
]
INTEGERS = ["0", "-1", "1.5", "99999999999999999999", "nan", "", "abc", "2" * 400, LONG]
NAMES = ["", "nosuch", "μ", "../../etc/passwd", LONG, "a=b", "hopf:mu", "--json"]
SETS = ["=", "mu", "mu=", "mu=nan", "nosuch=1", "mu=1e400", "=1", LONG + "=1", "mu=1,2"]


def _hostile_path(kind: str, draw, tmp: Path, world: dict[str, Path]) -> str:
    choice = draw(
        st.sampled_from(
            [
                "long",
                "deep_long",
                "missing_dir",
                "directory",
                "fifo",
                "device",
                "empty",
                "garbage",
                "exists",
                "bad_suffix",
                "proc",
                "trailing_slash",
                "valid",
            ]
        ),
        label=f"{kind} path",
    )
    suffix = {"plot": ".png", "dir": ""}.get(kind, ".nc")
    return {
        "long": str(tmp / ("n" * 300 + suffix)),
        "deep_long": str(tmp / "/".join(["d" * 200] * 25) / ("f" + suffix)),
        "missing_dir": str(tmp / "no" / "such" / ("f" + suffix)),
        "directory": str(world["dir"]),
        "fifo": str(world["fifo"]),
        "device": str(world["device"]),
        "empty": str(world["empty"]),
        "garbage": str(world["garbage"]),
        "exists": str(world["lco"] if kind == "in" else _existing(tmp, suffix)),
        "bad_suffix": str(tmp / "figure.xyz"),
        "proc": "/proc/bifid-fuzz" + suffix,
        "trailing_slash": str(tmp / ("f" + suffix)) + "/",
        "valid": str(tmp / ("fresh" + suffix)),
    }[choice]


def _existing(tmp: Path, suffix: str) -> Path:
    p = tmp / ("existing" + suffix)
    if suffix:
        p.write_bytes(b"not yours")
    else:
        p.mkdir(exist_ok=True)
        (p / "keep.txt").write_text("keep")
    return p


def _kind(param) -> str:
    """What an option's value means, from its name and type."""
    name = (param.name or "").lower()
    tname = getattr(getattr(param, "type", None), "name", "") or ""
    if getattr(param, "is_flag", False) or tname == "boolean":
        return "flag"
    if name == "plot":
        return "plot"
    if name == "out":
        return "out"
    if name in ("paths", "data", "datasets", "model", "inputs") or "path" in tname:
        return "in"
    if name == "sets":
        return "set"
    if tname in ("integer", "integer range"):
        return "int"
    if tname in ("float", "float range") or getattr(param, "nargs", 1) == 2:
        return "number"
    return "name"


def _replace(argv: list[str], param, values: list[str]) -> list[str]:
    """``argv`` with ``param``'s value(s) replaced (or added)."""
    opts = [o for o in getattr(param, "opts", []) if o.startswith("-")]
    if not opts:  # an argument: replace the first positional
        pos = next((i for i, a in enumerate(argv) if not a.startswith("-")), None)
        return values[:1] + argv[(pos + 1 if pos is not None else 0) :]
    nargs = max(1, getattr(param, "nargs", 1) or 1)
    out, i = [], 0
    while i < len(argv):
        if argv[i] in opts:
            i += 1 + nargs
            continue
        out.append(argv[i])
        i += 1
    return [*out, opts[0], *values[:nargs]]


@st.composite
def cases(draw, commands: list[str], tmp: Path, world: dict[str, Path]):
    name = draw(st.sampled_from(commands), label="command")
    cmd = COMMANDS[name]
    subst = {
        "LCO": str(world["lco"]),
        "FORCED": str(world["forced"]),
        "CSV": str(world["csv"]),
        "MODEL": str(world["dir"]),
        "OUT": str(tmp / "out.nc"),
        "OUTDIR": str(tmp / "outdir"),
    }
    argv = [subst.get(a, a) for a in BASE.get(name, [])]
    params = [p for p in cmd.params if p.name not in ("json_out", "quiet", "help")]
    for _ in range(draw(st.integers(1, 3), label="n mutations")):
        if not params:
            break
        param = draw(st.sampled_from(params), label="option")
        kind = _kind(param)
        n = max(1, getattr(param, "nargs", 1) or 1)
        if kind == "flag":
            opts = [o for o in param.opts if o.startswith("-")]
            argv = [*argv, opts[0]] if opts else argv
            continue
        pool = {"number": NUMBERS, "int": INTEGERS, "name": NAMES, "set": SETS}.get(kind)
        if pool is not None:
            values = [draw(st.sampled_from(pool), label=f"{param.name}") for _ in range(n)]
        else:
            values = [
                _hostile_path(
                    kind
                    if kind != "out" or "dir" not in " ".join(BASE.get(name, [])).lower()
                    else "dir",
                    draw,
                    tmp,
                    world,
                )
            ]
        argv = _replace(argv, param, values)
    if draw(st.integers(0, 4), label="unknown option") == 0:
        argv.append(draw(st.sampled_from(["--no-such-option", "--json=maybe", "-z", LONG])))
    if draw(st.booleans(), label="json"):
        argv.append("--json")
    if any(p.name == "quiet" for p in cmd.params):
        argv.append("--quiet")
    return name, [*name.split(), *argv]


# ---------------------------------------------------------------------- running a case
@contextlib.contextmanager
def _budget(seconds: float) -> Iterator[None]:
    """Interrupt the block after ``seconds`` as Ctrl-C would (SIGINT → KeyboardInterrupt)."""
    armed = [True]

    def on_alarm(signum, frame):
        if armed[0]:
            # again in 1 s if this one is lost (raised inside a garbage-collector callback)
            signal.setitimer(signal.ITIMER_REAL, 1.0)
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        armed[0] = False
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def run_case(argv: list[str], budget: float = BUDGET_S) -> tuple[int, str, str]:
    """Run ``bifid ARGV`` in-process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            with _budget(budget):
                main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except KeyboardInterrupt:  # the budget ran out outside the command's handling
            code = -1
    return code, out.getvalue(), err.getvalue()


def check_case(name: str, argv: list[str], code: int, out: str, err: str, tmp: Path) -> None:
    """The properties every case must keep (see the module docstring)."""
    shown = [a if len(a) < 200 else f"<{len(a)} chars>" for a in argv]
    OUTCOMES[f"{name}: exit {code}"] += 1
    assert code in DOCUMENTED, (shown, code, err[-2000:])
    assert "Traceback" not in err, (shown, err[-3000:])
    assert "internal error" not in err, (shown, err[-2000:])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert all(len(ln) <= 1000 for ln in lines), (shown, max(map(len, lines)))
    errors = [ln for ln in lines if ln.startswith("bifid: error:")]
    assert len(errors) == (0 if code == 0 else 1), (shown, code, err[-2000:])
    if "--json" in argv and code in (0, 3, 130) and out.strip():
        payload = json.loads(out)
        assert (isinstance(payload, dict) and "complete" in payload) or name == "systems", out
        if code == 130:
            assert payload["status"] == "interrupted" and payload["complete"] is False
    if code in (2, 4):
        assert out.strip() == "", (shown, out[:500])
    _check_outputs(tmp)


def _check_outputs(tmp: Path) -> None:
    """Every dataset and model left in ``tmp`` loads; no temporary file remains."""
    for p in tmp.rglob("*"):
        assert not re.search(r"\.tmp$|\.replaced-", p.name), f"left behind: {p}"
        if p.is_file() and p.suffix == ".nc" and p.name.startswith(("out", "fresh")):
            load_dataset(p)
        if p.is_file() and p.name == "model.json":
            load_model(p.parent)


def _fuzz(commands: list[str], world, data) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="fuzz-"))
    try:
        name, argv = data.draw(cases(commands, tmp, world))
        code, out, err = run_case(argv)
        check_case(name, argv, code, out, err, tmp)
    finally:
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)


GROUPS = {
    "continuation": ["continue", "frc", "scurve", "backbone", "systems"],
    "cbc": ["cbc"],
    "fit": [c for c in COMMANDS if c.startswith("fit ")],
    "data": ["import", "predict", "demo"],
}
OTHERS = [c for c in COMMANDS if not any(c in g for g in GROUPS.values())]


@FUZZ
@given(data=st.data())
def test_fuzz_continuation_commands(world, data):
    """``continue``, ``frc``, ``scurve``, ``backbone``, ``systems`` under hostile options."""
    _fuzz([c for c in GROUPS["continuation"] if c in COMMANDS], world, data)


@FUZZ
@given(data=st.data())
def test_fuzz_cbc(world, data):
    """``cbc`` under hostile options; an interrupted campaign file must stay loadable."""
    _fuzz(GROUPS["cbc"], world, data)


@FUZZ
@given(data=st.data())
def test_fuzz_fit(world, data):
    """``fit hopf|forced|mechanistic`` under hostile datasets, outputs and options."""
    _fuzz(GROUPS["fit"], world, data)


@FUZZ
@given(data=st.data())
def test_fuzz_import_predict_demo(world, data):
    """``import``, ``predict``, ``demo`` (and any command added later) under hostile input."""
    _fuzz([c for c in GROUPS["data"] if c in COMMANDS] + OTHERS, world, data)


@FUZZ
@given(data=st.data())
def test_fuzz_any_command(world, data):
    """Any command at all, hostile arguments mixed across commands."""
    _fuzz(sorted(COMMANDS), world, data)


def test_zz_fuzz_counts():
    """At least 150 cases ran; counts of outcomes (with ``-s``, and in
    ``$BIFID_FUZZ_REPORT`` when set)."""
    total = sum(OUTCOMES.values())
    report = os.environ.get("BIFID_FUZZ_REPORT")
    if report:
        Path(report).write_text(
            json.dumps(
                {"cases": total, "budget_s": BUDGET_S, "outcomes": dict(sorted(OUTCOMES.items()))},
                indent=1,
            )
        )
    print("\nCLI fuzz outcomes:", json.dumps(dict(sorted(OUTCOMES.items()))))
    if N_EXAMPLES >= 40:
        assert total >= 150, total
