"""Fault injection: what the operating system does to every command that reads or writes.

Outputs: names longer than the file system allows, missing or non-directory parents,
outputs that are directories, FIFOs or devices, unknown figure formats, outputs that
exist (refused without ``--force``), read-only and full file systems. Inputs: names too
long, FIFOs (which would block a reader forever), devices (``/dev/zero`` never ends),
directories, missing files, HDF5 files that take data from other files (external
storage, virtual datasets, external links).

Every case must end with the documented exit code (2 for what the command line can fix,
4 for the environment) and one line on stderr, no traceback, before any computation
(outputs are checked first), and must leave no file behind. Read-only and full file
systems are real: small tmpfs mounts in a private mount namespace (``unshare -m``, root
only; skipped with the reason elsewhere), exercised by a child process.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from bifid.cli import main
from bifid.data import LCORecord, lco_dataset, load_dataset, save_dataset

# commands that write, each with a small valid command line (OUT/OUTDIR/PLOT replaced)
WRITERS = {
    "import": ["import", "CSV", "--out", "OUT"],
    "continue": ["continue", "hopf", "--param", "mu", "--range", "-0.2", "0.2", "--out", "OUT"],
    "frc": ["frc", "duffing", "--forcing", "0.1", "--omega-range", "0.9", "1.1", "--out", "OUT"],
    "scurve": [
        "scurve",
        "duffing",
        "--omega",
        "1",
        "--forcing-range",
        "0.01",
        "0.2",
        "--out",
        "OUT",
    ],
    "backbone": ["backbone", "duffing", "--amplitude-range", "0.01", "0.5", "--out", "OUT"],
    "cbc": ["cbc", "hopf", "--protocol", "ppcbc", "--values", "0.1", "--out", "OUT"],
    "fit hopf": ["fit", "hopf", "LCO", "--out", "OUTDIR"],
    "fit forced": ["fit", "forced", "LCO", "--out", "OUTDIR"],
    "fit mechanistic": [
        "fit",
        "mechanistic",
        "LCO",
        "--model",
        "flutter",
        "--free",
        "ka2,ka3",
        "--out",
        "OUTDIR",
    ],
    "demo": ["demo", "forced", "--out", "OUTDIR"],
}
PLOTTERS = {  # commands with --plot
    "continue": WRITERS["continue"][:-2],
    "frc": WRITERS["frc"][:-2],
    "scurve": WRITERS["scurve"][:-2],
    "backbone": WRITERS["backbone"][:-2],
    "cbc": WRITERS["cbc"],
    "fit hopf": WRITERS["fit hopf"],
    "fit mechanistic": WRITERS["fit mechanistic"],
    "predict": ["predict", "MODEL", "--range", "-0.2", "0.2"],
}
# commands that read a dataset / model, with where the input goes (IN)
READERS = {
    "import": ["import", "IN", "--out", "OUT"],
    "fit hopf": ["fit", "hopf", "IN", "--out", "OUTDIR"],
    "fit forced": ["fit", "forced", "IN", "--out", "OUTDIR"],
    "fit mechanistic": [
        "fit",
        "mechanistic",
        "IN",
        "--model",
        "flutter",
        "--free",
        "ka2,ka3",
        "--out",
        "OUTDIR",
    ],
    "cbc --resume": [
        "cbc",
        "hopf",
        "--protocol",
        "ppcbc",
        "--values",
        "0.1",
        "--resume",
        "--out",
        "IN",
    ],
}
MAX_SECONDS = 20.0  # a refusal comes before any computation (JIT compiles take longer)


def run(argv: list[str], timeout: float = 60.0) -> tuple[int, str, str, float]:
    """``bifid ARGV`` in-process with a watchdog (a blocked read would hang the suite)."""
    out, err = io.StringIO(), io.StringIO()

    def watchdog(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, watchdog)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    t0 = time.perf_counter()
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    return code, out.getvalue(), err.getvalue(), time.perf_counter() - t0


def assert_refused(result, code: int, needle: str | None = None) -> None:
    rc, out, err, seconds = result
    assert rc == code, (rc, err)
    assert "Traceback" not in err and out.strip() == "", (out, err)
    errors = [ln for ln in err.splitlines() if ln.startswith("bifid: error:")]
    assert len(errors) == 1 and all(len(ln) < 1000 for ln in err.splitlines()), err
    if needle is not None:
        assert needle in errors[0], errors[0]
    assert seconds < MAX_SECONDS, f"refused only after {seconds:.1f} s"


def _leftovers(d: Path) -> list[str]:
    return sorted(
        p.name
        for p in d.rglob("*")
        if p.name.endswith(".tmp") or ".bifid-probe-" in p.name or ".replaced-" in p.name
    )


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("faults")
    t = np.arange(400) / 200.0
    recs = [
        LCORecord(
            param=p,
            signals=np.column_stack([a * np.sin(2 * np.pi * t), a * np.cos(2 * np.pi * t)]),
            sample_rate=200.0,
            stable=True,
            frequency=2 * np.pi,
        )
        for p, a in ((0.1, 0.3), (0.2, 0.45))
    ]
    f = {
        "LCO": d / "lco.nc",
        "CSV": d / "ok.csv",
        "MODEL": d / "model",
        "fifo": d / "fifo.nc",
        "dir": d / "a_dir",
        "file": d / "a_file",
        "device": d / "zero_device",
    }
    save_dataset(lco_dataset(recs, ["u1", "u2"], "mu", "", "hopf"), f["LCO"])
    rows = ["record,param,stable,time,h"] + [
        f"{r},{r + 1},1,{i / 100:.2f},{np.sin(2 * np.pi * i / 100):.6f}"
        for r in range(2)
        for i in range(200)
    ]
    f["CSV"].write_text("\n".join(rows) + "\n")
    f["MODEL"].mkdir()
    os.mkfifo(f["fifo"])
    f["dir"].mkdir()
    f["file"].write_text("x")
    with contextlib.suppress(OSError):  # a private /dev/zero twin; needs root
        os.mknod(f["device"], stat.S_IFCHR | 0o666, os.makedev(1, 5))
    return f


def _argv(template: list[str], files: dict[str, Path], **repl: str) -> list[str]:
    return [repl.get(a, str(files[a]) if a in files else a) for a in template]


# ------------------------------------------------------------------------------- outputs
OUTPUT_FAULTS = {
    # fault: (how to make the path, exit code, words in the message)
    "name too long": (lambda d, f: d / ("n" * 300 + ".nc"), 2, "allows"),
    "path too long": (lambda d, f: d.joinpath(*["d" * 250] * 20, "f.nc"), 2, "limit"),
    "missing parent": (lambda d, f: d / "no" / "such" / "f.nc", 2, "does not exist"),
    "parent is a file": (lambda d, f: f["file"] / "f.nc", 2, "not a directory"),
    "a FIFO": (lambda d, f: f["fifo"], 2, "FIFO"),
    "a device": (lambda d, f: f["device"], 2, "device"),
}


@pytest.mark.parametrize("fault", sorted(OUTPUT_FAULTS))
@pytest.mark.parametrize("command", sorted(WRITERS))
def test_output_faults(command, fault, files, tmp_path):
    """Check every output fault of every writer is refused with exit 2 before computing."""
    make, code, needle = OUTPUT_FAULTS[fault]
    if fault == "a device" and not files["device"].exists():
        pytest.skip("creating a device node needs root")
    target = make(tmp_path, files)
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = _argv(WRITERS[command], files, OUT=str(target), OUTDIR=str(target))
    if fault in ("a FIFO", "a device") and "OUTDIR" in WRITERS[command]:
        needle = "not a directory"
    assert_refused(run(argv), code, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == before and not _leftovers(tmp_path)
    assert stat.S_ISFIFO(os.stat(files["fifo"]).st_mode)  # never replaced by a file


@pytest.mark.parametrize("command", sorted(WRITERS))
def test_existing_outputs_need_force(command, files, tmp_path):
    """Check an existing output file, or a non-empty directory, is refused without --force
    and left as it was."""
    directory = "OUTDIR" in WRITERS[command]
    target = tmp_path / ("taken" if directory else "taken.nc")
    if directory:
        target.mkdir()
        (target / "notes.txt").write_text("mine")
    else:
        target.write_bytes(b"mine")
    argv = _argv(WRITERS[command], files, OUT=str(target), OUTDIR=str(target))
    assert_refused(run(argv), 2, "--force")
    kept = (target / "notes.txt") if directory else target
    assert kept.read_bytes() == b"mine" and not _leftovers(tmp_path)
    if not directory:  # a file output that is a directory is never written into
        assert_refused(run(_argv(WRITERS[command], files, OUT=str(files["dir"]))), 2, "directory")


@pytest.mark.parametrize(
    "fault, make, needle",
    [
        ("unknown format", lambda d: d / "figure.xyz", "unknown figure format"),
        ("no suffix", lambda d: d / "figure", "unknown figure format"),
        ("missing parent", lambda d: d / "no" / "figure.png", "does not exist"),
        ("name too long", lambda d: d / ("p" * 300 + ".png"), "allows"),
        ("a directory", lambda d: d, "directory"),
    ],
)
@pytest.mark.parametrize("command", sorted(PLOTTERS))
def test_plot_faults(command, fault, make, needle, files, tmp_path):
    """Check a bad --plot is refused with exit 2 before computing, for every plotter."""
    out = tmp_path / "outputs"
    out.mkdir()
    argv = _argv(PLOTTERS[command], files, OUT=str(out / "o.nc"), OUTDIR=str(out / "m"))
    assert_refused(run([*argv, "--plot", str(make(tmp_path))]), 2, needle)
    assert list(out.iterdir()) == []


# -------------------------------------------------------------------------------- inputs
def _external_storage(d: Path, files) -> Path:
    p = d / "external.nc"
    shutil.copy(files["LCO"], p)
    (d / "secret.bin").write_bytes(np.arange(4.0).tobytes())
    with h5py.File(p, "a") as h:
        h.create_dataset("leak", shape=(4,), dtype="f8", external=[(str(d / "secret.bin"), 0, 32)])
    return p


def _virtual(d: Path, files) -> Path:
    p = d / "virtual.nc"
    shutil.copy(files["LCO"], p)
    with h5py.File(p, "a") as h:
        layout = h5py.VirtualLayout(shape=(4,), dtype="f8")
        layout[:] = h5py.VirtualSource(str(d / "other.h5"), "x", shape=(4,))
        h.create_virtual_dataset("leak", layout)
    return p


def _external_link(d: Path, files) -> Path:
    p = d / "linked.nc"
    shutil.copy(files["LCO"], p)
    with h5py.File(p, "a") as h:
        h["leak"] = h5py.ExternalLink(str(files["LCO"]), "/")
    return p


INPUT_FAULTS = {
    "name too long": (lambda d, f: d / ("i" * 300 + ".nc"), "long"),
    "missing": (lambda d, f: d / "missing.nc", "does not exist"),
    "a FIFO": (lambda d, f: f["fifo"], "FIFO"),
    "a device": (lambda d, f: f["device"], "device"),
    "a directory": (lambda d, f: f["dir"], None),
    "external storage": (_external_storage, "outside itself"),
    "virtual dataset": (_virtual, "outside itself"),
    "external link": (_external_link, "outside itself"),
}


@pytest.mark.parametrize("fault", sorted(INPUT_FAULTS))
@pytest.mark.parametrize("command", sorted(READERS))
def test_input_faults(command, fault, files, tmp_path):
    """Check every input fault of every reader is refused with exit 2 and a message that
    names it (a FIFO is never opened, so nothing blocks)."""
    make, needle = INPUT_FAULTS[fault]
    if fault == "a device" and not files["device"].exists():
        pytest.skip("creating a device node needs root")
    src = make(tmp_path, files)
    out = tmp_path / "outputs"
    out.mkdir()
    argv = _argv(READERS[command], files, IN=str(src), OUT=str(out / "o.nc"), OUTDIR=str(out / "m"))
    if command == "cbc --resume" and fault == "a FIFO":
        needle = "FIFO"
    assert_refused(run(argv, timeout=30.0), 2, needle)
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("inside", ["model.json", "arrays.npz"])
def test_model_files_that_are_fifos(inside, tmp_path):
    """Check ``predict`` refuses a model directory whose files are FIFOs without blocking."""
    from bifid.io import save_model

    model = save_model(tmp_path / "m", "hopf_hybrid", {"a": 1.0}, {"x": np.arange(3.0)})
    (model / inside).unlink()
    os.mkfifo(model / inside)
    assert_refused(run(["predict", model, "--range", "0", "1", "--json"], timeout=30.0), 2)


def test_system_file_that_is_a_fifo(tmp_path):
    """Check a SYSTEM path that is a FIFO is refused, not read (it would block)."""
    fifo = tmp_path / "system.toml"
    os.mkfifo(fifo)
    assert_refused(run(["continue", fifo, "--range", "0", "1"], timeout=5.0), 2)


# ----------------------------------------------------- read-only and full file systems
_CHILD = textwrap.dedent("""
    import contextlib, io, json, sys, time
    from bifid.cli import main
    results = []
    for argv in json.loads(sys.argv[1]):
        out, err = io.StringIO(), io.StringIO()
        t0 = time.perf_counter()
        code = 0
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main(argv)
            except SystemExit as exc:
                code = exc.code
        results.append({"argv": argv, "code": code, "stdout": out.getvalue(),
                        "stderr": err.getvalue(), "seconds": time.perf_counter() - t0})
    print("RESULTS " + json.dumps(results))
""")


def _in_namespace(mounts: str, cases: list[list[str]]) -> list[dict]:
    """Run ``cases`` in a child process inside a private mount namespace set up by
    ``mounts`` (shell commands); skip when the platform does not allow it."""
    if sys.platform != "linux" or os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs Linux, root and unshare(1) for private tmpfs mounts")
    probe = subprocess.run(
        ["unshare", "-m", "--propagation", "private", "true"], capture_output=True, text=True
    )
    if probe.returncode != 0:
        pytest.skip(f"no private mount namespace here: {probe.stderr.strip()[:200]}")
    script = f'{mounts} && exec {sys.executable} -c "$0" "$1"'
    r = subprocess.run(
        [
            "unshare",
            "-m",
            "--propagation",
            "private",
            "sh",
            "-c",
            script,
            _CHILD,
            json.dumps(cases),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "BIFID_JAX_CACHE": ""},
    )
    line = next((ln for ln in r.stdout.splitlines() if ln.startswith("RESULTS ")), None)
    assert line is not None, (r.returncode, r.stdout[-2000:], r.stderr[-4000:])
    return json.loads(line[len("RESULTS ") :])


def _check_env_refusals(results: list[dict], needle: str) -> None:
    for res in results:
        assert_refused((res["code"], res["stdout"], res["stderr"], res["seconds"]), 4, needle)


def test_read_only_file_system(files, tmp_path):
    """Check every writer refuses a read-only file system (exit 4) before computing."""
    ro = tmp_path / "ro"
    ro.mkdir()
    cases = [
        _argv(WRITERS[c], files, OUT=str(ro / "o.nc"), OUTDIR=str(ro / "m"))
        for c in sorted(WRITERS)
    ]
    cases += [
        [
            *_argv(
                PLOTTERS[c], files, OUT=str(tmp_path / f"{i}.nc"), OUTDIR=str(tmp_path / f"m{i}")
            ),
            "--plot",
            str(ro / "f.png"),
        ]
        for i, c in enumerate(sorted(PLOTTERS))
    ]
    results = _in_namespace(f"mount -t tmpfs -o ro,size=64k tmpfs {ro}", cases)
    _check_env_refusals(results, "read-only file system")


def test_full_file_system(files, tmp_path):
    """Check every writer refuses a full file system (exit 4) before computing."""
    full = tmp_path / "full"
    full.mkdir()
    cases = [
        _argv(WRITERS[c], files, OUT=str(full / "o.nc"), OUTDIR=str(full / "m"))
        for c in sorted(WRITERS)
    ]
    fill = (
        f"mount -t tmpfs -o size=256k tmpfs {full} && "
        f"(dd if=/dev/zero of={full}/filler bs=4k 2>/dev/null || true)"
    )
    results = _in_namespace(fill, cases)
    _check_env_refusals(results, "no space left")


def test_disk_fills_up_while_writing(files, tmp_path):
    """Check a dataset larger than the space left ends in exit 4 and one line -- not an
    HDF5 crash -- with the previous file intact and no temporary file left."""
    small = tmp_path / "small"
    small.mkdir()
    big = tmp_path / "big.csv"
    rows = ["record,param,stable,time,h,v"] + [
        f"{r},{r + 1},1,{i / 1000:.3f},{np.sin(i / 7 + r):.9f},{np.cos(i / 3 * r):.9f}"
        for r in range(4)
        for i in range(6000)
    ]
    big.write_text("\n".join(rows) + "\n")
    cases = [
        ["import", str(files["CSV"]), "--out", str(small / "d.nc")],
        ["import", str(big), "--out", str(small / "d.nc"), "--force"],
        ["import", str(big), "--out", str(small / "e.nc")],
    ]
    results = _in_namespace(f"mount -t tmpfs -o size=160k tmpfs {small}", cases)
    assert results[0]["code"] == 0, results[0]["stderr"]
    for res in results[1:]:
        assert res["code"] == 4, res["stderr"]
        assert "no space left" in res["stderr"] and "Traceback" not in res["stderr"]
        assert len(res["stderr"].strip().splitlines()) == 1, res["stderr"]


def test_library_write_to_a_full_disk(tmp_path):
    """Check ``save_dataset`` on a full disk raises OSError(ENOSPC) and leaves no file: the
    dataset is serialised in memory, so HDF5 never writes to the full file system."""
    script = textwrap.dedent(f'''
        import errno, numpy as np
        from bifid.data import LCORecord, lco_dataset, save_dataset
        t = np.arange(20000) / 100.0
        recs = [LCORecord(param=float(k), signals=np.random.default_rng(k).random((20000, 2)),
                          sample_rate=100.0, stable=True, frequency=1.0) for k in range(4)]
        try:
            save_dataset(lco_dataset(recs, ["a", "b"]), "{tmp_path}/full/d.nc")
        except OSError as exc:
            print("RESULTS", exc.errno == errno.ENOSPC)
    ''')
    (tmp_path / "full").mkdir()
    if sys.platform != "linux" or os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs Linux, root and unshare(1) for private tmpfs mounts")
    r = subprocess.run(
        [
            "unshare",
            "-m",
            "--propagation",
            "private",
            "sh",
            "-c",
            f'mount -t tmpfs -o size=256k tmpfs {tmp_path}/full && exec {sys.executable} -c "$0"',
            script,
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0 and "RESULTS True" in r.stdout, (r.returncode, r.stderr[-3000:])
    assert "Traceback" not in r.stderr


def test_output_left_by_an_interrupted_write_is_the_old_one(files, tmp_path, monkeypatch):
    """Check an interruption while a dataset is written keeps the previous file intact."""
    out = tmp_path / "d.nc"
    assert run(["import", files["CSV"], "--out", out])[0] == 0
    before = out.read_bytes()

    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupted)
    rc, stdout, err, _ = run(["import", files["CSV"], "--out", out, "--force", "--json"])
    assert rc == 130 and json.loads(stdout)["status"] == "interrupted", (rc, err)
    assert out.read_bytes() == before and not _leftovers(tmp_path)
    assert load_dataset(out).sizes["record"] == 2
