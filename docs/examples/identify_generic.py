"""The three identification methods through one script: fit → predict_diagram → JSON → plot.

Every bifid model is an estimator with the same contract (``bifid.identify``): ``fit`` on a
dataset, ``predict_diagram`` with the options of ``bifid predict``, a ``Diagram`` whose
``to_json()`` is the CLI's output and which ``bifid.report.plot_diagram`` draws, ``save`` to a
directory that ``bifid predict`` reads. So one function, :func:`identify`, runs any of them;
only the configuration in :func:`main` differs.

Run: ``python docs/examples/identify_generic.py [OUT_DIR]`` (a minute or two, most of it
compilation). The data are small and written down in closed form from systems whose answers
are known, so the predictions can be checked against the truth: the limit cycles of the
subcritical Hopf normal form (system ``hopf``: circles, Hopf point at mu = 0, fold of cycles
at mu = -0.25) and the forced responses of a hardening Duffing oscillator after first-order
averaging. With measured data, pass the netCDF files of ``bifid cbc`` or ``bifid import``
instead.
"""

# bifid-example: slow (the test suite runs its main() in-process)

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bifid.data import ForcedRecord, LCORecord, forced_dataset, lco_dataset, save_dataset
from bifid.identify import ForcedKernelModel, HopfHybridModel, MechanisticModel
from bifid.report import plot_diagram, save_figure

# Averaged Duffing oscillator q'' + 2 zeta q' + q + gamma q^3 = F cos(Omega t): on the slow
# flow rho' = a(rho) + G sin(psi), rho psi' = (b(rho) - Omega) rho + G cos(psi) with
# a = -zeta rho, b = 1 + 3 gamma rho^2 / 8 and G = F / 2.
ZETA, GAMMA = 0.01, 0.4


def identify(model: Any, dataset: Path, question: dict[str, Any], out: Path) -> dict[str, Any]:
    """Fit ``model`` to ``dataset``, ask it ``question``, save the model, the JSON and the
    figure."""
    model.fit(dataset)
    model.save(out / model.model_type)
    diagram = model.predict_diagram(**question)
    result = diagram.to_json()
    (out / f"{model.model_type}.json").write_text(json.dumps(result, indent=1))
    save_figure(
        plot_diagram(diagram, title=f"{model.model_type}: predicted diagram"),
        out / f"{model.model_type}.png",
    )
    return result


def hopf_radius(mu: np.ndarray, stable: bool) -> np.ndarray:
    """Cycle radius of the ``hopf`` system (defaults: r' = mu r + r^3 - r^5)."""
    return np.sqrt((1 + (1 if stable else -1) * np.sqrt(1 + 4 * np.asarray(mu))) / 2)


def limit_cycles(path: Path) -> Path:
    """Stable and unstable limit cycles of the ``hopf`` system, 2.5 periods each at 50 Hz."""
    t = np.arange(800) / 50.0
    records = [
        LCORecord(
            param=mu,
            signals=hopf_radius(mu, stable) * np.column_stack([np.cos(t), np.sin(t)]),
            sample_rate=50.0,
            stable=stable,
        )
        for stable, values in ((True, (-0.2, -0.12, -0.05, 0.05)), (False, (-0.2, -0.12, -0.05)))
        for mu in values
    ]
    save_dataset(
        lco_dataset(records, ["u1", "u2"], param_name="mu", system="hopf", source="hopf"),
        path,
    )
    return path


def duffing_frc(forcing: float, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frequency response ``(Omega, rho)`` of the averaged Duffing oscillator, explicit in
    the phase ``psi`` of the fixed points: ``rho = G sin(psi) / zeta``,
    ``Omega = b(rho) + G cos(psi) / rho``."""
    rho = forcing / 2 * np.sin(psi) / ZETA
    return 1 + 3 * GAMMA * rho**2 / 8 + forcing / 2 * np.cos(psi) / rho, rho


def forced_responses(path: Path) -> Path:
    """Two frequency response curves of the averaged Duffing oscillator, 16 points each,
    two periods of 64 samples with the force."""
    records = []
    psi = np.linspace(0.15, np.pi - 0.15, 16)
    for curve, forcing in enumerate((0.01, 0.02)):
        omegas, rhos = duffing_frc(forcing, psi)
        for omega, rho, phase in zip(omegas, rhos, psi, strict=True):
            t = np.arange(128) * 2 * np.pi / (64 * omega)
            records.append(
                ForcedRecord(
                    omega=float(omega),
                    forcing=forcing,
                    signals=(-rho * np.cos(omega * t + phase))[:, None],
                    sample_rate=64 * omega / (2 * np.pi),
                    force=forcing * np.cos(omega * t),
                    curve=curve,
                )
            )
    save_dataset(forced_dataset(records, ["q"], observed="q", source="duffing"), path)
    return path


def main(out: Path) -> dict[str, dict[str, Any]]:
    out.mkdir(parents=True, exist_ok=True)
    lcos, forced = limit_cycles(out / "lcos.nc"), forced_responses(out / "frcs.nc")
    runs = [
        (
            MechanisticModel("hopf", ("a2",), params={"a2": 0.8}, n_mesh=16),
            lcos,
            {"range": (-0.4, 0.2)},
        ),
        (
            HopfHybridModel(
                n_harmonics=6,
                width=8,
                n_lbfgs=150,
                n_ensemble=2,
                regularization=1e-6,
                stopping="final",
                omega_harmonics=2,
                omega_regularization=1e-4,
            ),
            lcos,
            {"range": (-0.4, 0.2), "n_points": 60},
        ),
        (
            ForcedKernelModel(n_restarts=0, max_phi_points=64),
            forced,
            {"forcing": 0.015, "range": (0.95, 1.2)},
        ),
    ]
    return {
        model.model_type: identify(model, data, question, out) for model, data, question in runs
    }


if __name__ == "__main__":
    results = main(Path(sys.argv[1] if len(sys.argv) > 1 else "identify-generic"))
    for name, diagram in results.items():
        print(f"{name}: {diagram['kind']}, complete: {diagram['complete']}")
