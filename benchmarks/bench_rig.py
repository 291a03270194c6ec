"""Virtual-rig benchmark: the sample loop generated from each system's field against the
hand-written per-system kernels it replaced.

Run from the repository root or the benchmarks directory::

    .venv/bin/python benchmarks/bench_rig.py            # writes BENCHMARKS.md section "rig"
    .venv/bin/python benchmarks/bench_rig.py --quick    # flutter only, shorter, prints only

Measures, in one run, for every built-in system with a CBC controller in the loop (the
system's own sample rate, target type and gains; 1 % measurement noise):

1. the generated loop (:mod:`bifid.cbc._fastloop` with the field translated from its
   jaxpr, error control and safety gate included) against the hand-written kernel
   (``benchmarks/_handwritten_rig.py``, fixed-step RK4, no gate), both called on the same
   inputs, interleaved, ``repeats`` times: medians of wall and CPU time per run, the ratio
   generated / hand-written, simulated seconds per wall second (real-time factor), and the
   largest difference between their measured outputs (sample for sample);
2. the same run through ``VirtualRig.run`` (noise drawn, measurement assembled): what a
   CBC protocol gets;
3. compile times, each in a fresh process with empty caches: tracing and translating the
   field, numba's first compilation of the generated module, the hand-written kernel's
   first compilation, and loading the generated module from the disk cache in a second
   process;
4. a system from a file (``docs/examples/systems/brusselator.toml``): a six-value PP-CBC
   campaign through the CLI with no option but the values (``--campaign``: this part
   only), in a fresh process with empty caches (rig loop and JAX), then again with the
   caches filled; wall and CPU time of the process, points measured, and their error
   against the cycles Newton-corrected at the same parameter (the campaign's truth).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _handwritten_rig as hand  # noqa: E402
import bifid  # noqa: E402, F401
from _report import write_section  # noqa: E402
from bifid.cbc import (  # noqa: E402
    EllipticTarget,
    FourierTarget,
    PDController,
    PolarTarget,
    VirtualRig,
)
from bifid.systems import get_system  # noqa: E402

SYSTEMS = ("flutter", "hopf", "vanderpol", "duffing", "shaw_pierre")
N_SAMPLES = 100_000  # per timed run


def scenario(name: str) -> VirtualRig:
    """A rig of ``name`` with its CBC controller on (and its forcing, if forced)."""
    s = get_system(name)
    if name == "flutter":
        rig = VirtualRig(
            s,
            {"U": 16.0},
            outputs=("h", "alpha"),
            sample_rate=5000.0,
            noise={"h": 7.4e-5, "alpha": 2.2e-4},
            x0=[0.012, 0, 0.04, 0, 0, 0],
        )
        c = np.zeros(21)
        c[0], c[1:] = 0.013, 1e-4 * np.random.default_rng(0).normal(size=20)
        rig.set_controller(
            PDController(-150.0, -20.0, "h", "alpha", filter_hz=100.0),
            PolarTarget(c, scale=(1.0, 3.3), origin=(0.001, -0.01)),
        )
    elif name in ("hopf", "vanderpol"):
        sig = ("u1", "u2") if name == "hopf" else ("z1", "z1_dot")
        rig = VirtualRig(
            s,
            {"mu": -0.05 if name == "hopf" else 0.5},
            outputs=(sig[0], sig[1].removesuffix("_dot")),
            sample_rate=200.0,
            noise=1e-3,
            x0=[0.2, 0.0],
        )
        rig.set_controller(
            PDController(1.0, 0.0 if name == "hopf" else 1.0, *sig),
            EllipticTarget(0.2 if name == "hopf" else 1.5, 1.0),
        )
    else:
        out = "q" if name == "duffing" else "x1"
        rig = VirtualRig(
            s, outputs=(out,), sample_rate=100.0, noise=3e-4, x0=[0.1] + [0.0] * (s.n_states - 1)
        )
        rig.set_forcing(0.02, 1.05)
        rig.set_controller(
            PDController(0.5, 0.5, out, out + "_dot"), FourierTarget([0.0, 0.3, 0.01, -0.1, 0.005])
        )
    return rig


def kernels(rig: VirtualRig, n: int):
    """Two closures running ``n`` samples from the rig's current state: the generated loop
    and the hand-written kernel, on the same inputs; each returns the measured outputs."""
    loop = rig._loop
    assert loop is not None, "the generated loop is not in use"
    eps = np.random.default_rng(1).standard_normal((n, len(rig.output_names))) * rig._noise
    x0 = rig.state
    state = (
        x0,
        x0[list(rig._cfg.out_idx)],
        np.zeros(len(rig.output_names)),
        0.0,
        np.abs(x0),
        rig._cfg.initial_steps(),
    )
    consts = hand.prepare_constants(rig.system.name, rig._p)
    sid = hand.SYSTEM_IDS[rig.system.name]

    def arguments():
        return rig._engines.kernel_arguments(
            rig._p, rig._r, rig._directions, state, eps, rig.forcing, 0.0, rig._ctrl
        )

    def generated():
        args = arguments()
        loop.module.run_block(*args)
        return args[-1][0]

    def handwritten():
        _, _, b, e, (x, yprev, dfilt, _), steps, flags, reals, out_idx, noise, tv, _, outs = (
            arguments()
        )
        f, g = flags.tolist(), reals.tolist()
        hand.run_block(
            sid,
            consts,
            b,
            e,
            x,
            yprev,
            dfilt,
            g[0],
            out_idx,
            noise,
            bool(f[0]),
            *g[1:5],
            f[1],
            tv,
            f[2],
            bool(f[3]),
            f[4],
            bool(f[5]),
            *g[5:10],
            bool(f[6]),
            g[10],
            g[11],
            int(steps[0]),
            False,
            *outs,
        )
        return outs[0]

    return generated, handwritten


def _clock(fn) -> tuple[float, float]:
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def speed(name: str, seconds: float, repeats: int) -> dict:
    rig = scenario(name)
    n = round(seconds * rig.sample_rate)
    gen, hw = kernels(rig, n)
    diff = float(np.max(np.abs(gen() - hw())))  # also the first (compiling) calls
    gen_t, hw_t, rig_t = [], [], []
    for _ in range(repeats):  # interleaved, so that load changes hit both alike
        gen_t.append(_clock(gen))
        hw_t.append(_clock(hw))
        rig_t.append(_clock(lambda: rig.run(seconds)))

    def med(ts, k):
        return statistics.median(t[k] for t in ts)

    return {
        "system": name,
        "fs": rig.sample_rate,
        "sim_s": seconds,
        "n": n,
        "diff": diff,
        "gen_wall": med(gen_t, 0),
        "gen_cpu": med(gen_t, 1),
        "hw_wall": med(hw_t, 0),
        "hw_cpu": med(hw_t, 1),
        "rig_wall": med(rig_t, 0),
        "rig_cpu": med(rig_t, 1),
        "ratio_wall": statistics.median(g[0] / h[0] for g, h in zip(gen_t, hw_t, strict=True)),
        "ratio_cpu": statistics.median(g[1] / h[1] for g, h in zip(gen_t, hw_t, strict=True)),
    }


def jax_engine(seconds: float, repeats: int) -> dict:
    """The flutter scenario on the JAX engine (the fallback for untranslatable fields)."""
    rig = scenario("flutter")
    jx = VirtualRig(
        rig.system,
        rig.params,
        outputs=rig.output_names,
        sample_rate=5000.0,
        noise={"h": 7.4e-5, "alpha": 2.2e-4},
        x0=rig.state,
        engine="jax",
    )
    jx.set_controller(*rig.controller)
    t0 = time.perf_counter()
    jx.run(1.0)
    compile_s = time.perf_counter() - t0
    times = [_clock(lambda: jx.run(seconds)) for _ in range(repeats)]
    wall = statistics.median(t[0] for t in times)
    return {
        "compile_s": compile_s,
        "realtime": seconds / wall,
        "cpu_ns": 1e9 * statistics.median(t[1] for t in times) / (seconds * 5000.0),
    }


def probe(name: str) -> dict:
    """Compile times in this (fresh) process, caches as given by the environment."""
    from bifid.cbc._codegen import translate

    s = get_system(name)
    t0 = time.perf_counter()
    translate(s.field, s.n_states, len(s.parameters))
    t_translate = time.perf_counter() - t0
    rig = scenario(name)
    gen, hw = kernels(rig, 10)
    t_gen, _ = _clock(gen)
    t_hw, _ = _clock(hw)
    return {"translate_s": t_translate, "generated_s": t_gen, "handwritten_s": t_hw}


def compile_times(name: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, BIFID_CACHE_DIR=tmp, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"))
        cmd = [sys.executable, str(Path(__file__).resolve()), "--probe", name]
        cold, warm = (
            json.loads(
                subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
                .stdout.strip()
                .splitlines()[-1]
            )
            for _ in range(2)
        )
    return {
        "translate_s": cold["translate_s"],
        "cold_s": cold["generated_s"],
        "warm_s": warm["generated_s"],
        "hand_cold_s": cold["handwritten_s"],
    }


def _table(rows: list[dict]) -> list[str]:
    md = [
        "| system | f_s [Hz] | generated [ns/sample] | hand-written [ns/sample] | "
        "generated / hand-written (wall, CPU) | real time × (generated) | "
        "VirtualRig.run real time × | max Δ output |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ns = 1e9 / r["n"]
        md.append(
            f"| {r['system']} | {r['fs']:.0f} | {r['gen_wall'] * ns:.0f} "
            f"(CPU {r['gen_cpu'] * ns:.0f}) | {r['hw_wall'] * ns:.0f} (CPU {r['hw_cpu'] * ns:.0f}) "
            f"| {r['ratio_wall']:.2f}, {r['ratio_cpu']:.2f} | {r['sim_s'] / r['gen_wall']:.0f} | "
            f"{r['sim_s'] / r['rig_wall']:.0f} | {r['diff']:.1e} |"
        )
    return md


USER_SYSTEM = HERE.parent / "docs" / "examples" / "systems" / "brusselator.toml"
USER_VALUES = "2.05,2.1,2.2,2.3,2.4,2.5"


def _cli_run(args: list[str], env: dict[str, str]) -> tuple[dict, float, float, int]:
    """``bifid ARGS`` in a fresh process: (JSON, wall, CPU of the child, exit code)."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "bifid", *args], capture_output=True, text=True, env=env
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    try:
        out = json.loads(r.stdout)
    except json.JSONDecodeError:
        out = {"error": r.stderr.strip().splitlines()[-1:] or ["no output"]}
    return out, wall, cpu, r.returncode


def user_campaign() -> list[str]:
    """A six-value PP-CBC campaign on a system from a file, cold and with warm caches."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "BIFID_CACHE_DIR": str(Path(tmp) / "cache"),
            "BIFID_JAX_CACHE": str(Path(tmp) / "jax"),
        }
        for run in ("empty caches", "caches filled"):
            nc = Path(tmp) / f"{run.split()[0]}.nc"
            args = ["cbc", str(USER_SYSTEM), "--values", USER_VALUES, "--out", str(nc), "--json"]
            out, wall, cpu, code = _cli_run(args, env)
            pts = out.get("points", [])
            errs = [
                max(abs(e) for e in p["relative_error"].values())
                for p in pts
                if p.get("relative_error")
            ]
            worst = 100 * max(errs) if errs else float("nan")
            rows.append(
                f"| {run} | {code} | {len(pts)} / 6 | {len(out.get('failures', []))} | "
                f"{worst:.3f} % | **{wall:.1f} s** | {cpu:.1f} s |"
            )
            print(
                f"user campaign, {run}: exit {code}, wall {wall:.1f} s, CPU {cpu:.1f} s",
                file=sys.stderr,
            )
    load = os.getloadavg()
    return [
        "### A system from a file: six-value PP-CBC campaign through the CLI",
        "",
        "`bifid cbc docs/examples/systems/brusselator.toml --values "
        f"{USER_VALUES} --out b.nc --json`: every setting derived from the system "
        "(linearisation, first continuation run); the rig loop generated from the "
        "equations in the file. Fresh process each; the first with empty caches (the rig "
        "loop's numba compilation and JAX's programs included), the second with them filled. "
        "Error: largest relative amplitude error of any output against the cycle "
        "Newton-corrected at the same b.",
        "",
        "| run | exit | LCOs | failures | max error | wall | CPU |",
        "|---|---|---|---|---|---|---|",
        *rows,
        "",
        f"Load average after the runs: {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} "
        "(1/5/15 min, 2 cores; wall exceeds CPU by what other jobs took).",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="flutter only; print, do not write")
    ap.add_argument("--campaign", action="store_true", help="part 4 only (writes its section)")
    ap.add_argument("--probe", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.probe:
        print(json.dumps(probe(args.probe)))
        return
    if args.campaign:
        text = "\n".join(user_campaign())
        print(text)
        write_section("rig_user", text)
        return
    systems = ("flutter",) if args.quick else SYSTEMS
    repeats = 5 if args.quick else 9
    rows, compiles = [], {}
    for name in systems:
        fs = float(scenario(name).sample_rate)
        rows.append(speed(name, (N_SAMPLES // (4 if args.quick else 1)) / fs, repeats))
        compiles[name] = compile_times(name)
        print(f"{name}: {rows[-1]}\n  compile {compiles[name]}", file=sys.stderr)
    md = [
        "Virtual rig: the sample loop generated from each system's own field (translated from",
        "its jaxpr to scalar code, compiled by numba, with per-sample RK4 error control and the",
        "safety gate) against the hand-written per-system kernels it replaced (fixed-step RK4,",
        f"no gate), same inputs, interleaved; medians of {repeats} runs of {rows[0]['n']} samples",
        "each (CBC controller on, measurement noise); ns per sample of wall and CPU time,",
        "real-time factor from the wall time.",
        "",
        *_table(rows),
        "",
        "Compile times (fresh processes, empty caches): translation of the field, first run",
        "of the generated loop (numba compilation), the same in a second process (disk cache),",
        "first run of the hand-written kernel.",
        "",
        "| system | translate [s] | generated, cold [s] | generated, cached [s] | "
        "hand-written, cold [s] |",
        "|---|---|---|---|---|",
    ]
    md += [
        f"| {k} | {v['translate_s']:.2f} | {v['cold_s']:.1f} | {v['warm_s']:.2f} | "
        f"{v['hand_cold_s']:.1f} |"
        for k, v in compiles.items()
    ]
    jx = jax_engine(4096 * 4 / 5000.0, 3)
    md += [
        "",
        f"The JAX engine (one `lax.scan` per block; for fields with an operation the "
        f"generator cannot express on the state) runs the flutter scenario at "
        f"{jx['realtime']:.0f}× real time (CPU {jx['cpu_ns']:.0f} ns per sample; first "
        f"block compiled in {jx['compile_s']:.1f} s).",
        "",
        "Command: `.venv/bin/python benchmarks/bench_rig.py`.",
    ]
    text = "\n".join(md)
    print(text)
    if not args.quick:
        write_section("rig", "## Virtual rig: generated loop\n\n" + text)
        write_section("rig_user", "\n".join(user_campaign()))


if __name__ == "__main__":
    main()
