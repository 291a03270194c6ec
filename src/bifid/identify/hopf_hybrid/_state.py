"""The fitted hybrid model as data: every array and setting predictions need, and how they
are written to and read from a model file."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bifid.identify.hopf_hybrid._map import MapConfig, a2_of, mlp, mlp_static, u12
from bifid.identify.hopf_hybrid._observe import ObservationModel
from bifid.identify.hopf_hybrid._speed import SpeedConfig, init_speed_params

__all__ = [
    "N_GRID_INVERSE",
    "HybridState",
    "member",
    "plane_angles",
    "stack",
    "states_from_json",
    "states_to_json",
    "u12_batch",
    "u12_cycles",
]

N_GRID_INVERSE = 2048  # phases for the inversion of eq. 5.12


def stack(trees: list) -> Any:
    """Stack pytrees of equal structure along a new leading axis (ensemble members)."""
    return jax.tree_util.tree_map(lambda *x: np.stack([np.asarray(v) for v in x]), *trees)


def member(tree: Any, s: int) -> Any:
    """Member ``s`` of stacked pytrees."""
    return jax.tree_util.tree_map(lambda x: x[s], tree)


@functools.lru_cache(maxsize=16)
def _u12_compiled(width: int, depth: int):
    static = mlp_static(3, 2, width, depth)
    return jax.jit(lambda mp, u, m: jax.vmap(lambda ui: u12(mp, static, ui, m))(u))


def u12_batch(mp: Any, config: MapConfig, u: np.ndarray, mu_t: float) -> np.ndarray:
    """:math:`\\mathbf U_{12}` of one member at points ``u`` (n, 2) and parameter ``mu_t``."""
    return np.asarray(
        _u12_compiled(config.width, config.depth)(mp, jnp.asarray(u), jnp.asarray(mu_t))
    )


@functools.lru_cache(maxsize=16)
def _u12_cycles_compiled(width: int, depth: int):
    static = mlp_static(3, 2, width, depth)
    one = jax.vmap(lambda mp, u, m: u12(mp, static, u, m), in_axes=(None, 0, None))
    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0)))


def u12_cycles(mp: Any, config: MapConfig, u: np.ndarray, mu_t: np.ndarray) -> np.ndarray:
    r""":math:`\mathbf U_{12}` of one member on several cycles at once: points ``u``
    (n, k, 2) of cycle ``j`` at parameter ``mu_t[j]`` → (n, k, 2)."""
    return np.asarray(
        _u12_cycles_compiled(config.width, config.depth)(mp, jnp.asarray(u), jnp.asarray(mu_t))
    )


def plane_angles(
    mp: Any, config: MapConfig, mu_t: float, rho: float, centre: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Polar angles about ``centre`` of one member's model cycle ``rho`` at
    ``N_GRID_INVERSE`` normal-form phases (the grid of the inversion of eq. 5.12)."""
    phi = np.linspace(0.0, 2 * np.pi, N_GRID_INVERSE, endpoint=False)
    u = rho * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    d = u12_batch(mp, config, u, mu_t) - np.asarray(centre)[None, :]
    return phi, np.arctan2(d[:, 1], d[:, 0])


@dataclass
class HybridState:
    """Everything a fitted hybrid model predicts from.

    Attributes
    ----------
    map_config, speed_config : MapConfig, SpeedConfig
    map_params, speed_params : dict of ndarray
        Parameters of every ensemble member (leading axis: member).
    observation : list of ObservationModel
        Regression of the other signals, per member (empty with two signals).
    plane : (int, int)
        Columns of the signals forming the normal-form plane.
    others : tuple of int
        Columns of the regressed signals.
    mu_c, mu_s : float
        Normalisation of the parameter, :math:`\\tilde\\mu = (\\mu - \\mu_c)/\\mu_s`.
    z_scale : ndarray
        Scale of each signal.
    white : ndarray of shape (2, 2)
        Whitening of the plane.
    direction : float
        Rotation of the measured orbits in the plane (+1 counter-clockwise).
    q5 : float
        Quintic coefficient (1 or 0).
    a2_mode : str
        Sign constraint of :math:`a_2`.
    omega_scale : float
        :math:`\\omega_s` of the speed.
    signal_names, param_name, param_units, signal_units
    primary : int
        The medoid member, used for predictions.
    """

    map_config: MapConfig
    speed_config: SpeedConfig
    map_params: dict[str, Any]
    speed_params: dict[str, Any]
    observation: list[ObservationModel]
    plane: tuple[int, int]
    others: tuple[int, ...]
    mu_c: float
    mu_s: float
    z_scale: np.ndarray
    white: np.ndarray
    direction: float
    q5: float
    a2_mode: str
    omega_scale: float
    signal_names: tuple[str, ...]
    param_name: str
    param_units: str = ""
    signal_units: dict[str, str] = field(default_factory=dict)
    primary: int = 0

    @property
    def n_members(self) -> int:
        return int(np.asarray(self.map_params["mu0"]).shape[0])

    def mu_t(self, mu: Any) -> np.ndarray:
        """Normalised parameter."""
        return (np.asarray(mu, dtype=float) - self.mu_c) / self.mu_s

    def raw(self, mu_t: Any) -> np.ndarray:
        """Raw parameter of a normalised one."""
        return np.asarray(mu_t, dtype=float) * self.mu_s + self.mu_c

    def a2(self, s: int) -> float:
        """:math:`a_2` of member ``s`` (normalised units)."""
        return float(a2_of(jnp.asarray(self.map_params["alpha"][s]), self.a2_mode))

    def mu0_t(self, s: int) -> float:
        """Normalised Hopf point of member ``s``."""
        return float(self.map_params["mu0"][s])

    # ------------------------------------------------------------------ persistence
    _SCALARS = (
        "plane",
        "others",
        "mu_c",
        "mu_s",
        "direction",
        "q5",
        "a2_mode",
        "omega_scale",
        "signal_names",
        "param_name",
        "param_units",
        "signal_units",
        "primary",
    )

    def to_json(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """JSON-able settings and numeric arrays of the state."""
        arrays: dict[str, np.ndarray] = {"z_scale": self.z_scale, "white": self.white}
        for j, leaf in enumerate(jax.tree_util.tree_leaves(self.map_params)):
            arrays[f"map_{j}"] = np.asarray(leaf)
        for j, leaf in enumerate(jax.tree_util.tree_leaves(self.speed_params)):
            arrays[f"speed_{j}"] = np.asarray(leaf)
        for s, obs in enumerate(self.observation):
            arrays.update(obs.arrays(f"obs{s}_"))
        settings = {k: getattr(self, k) for k in self._SCALARS}
        settings.update(
            map_config=dict(self.map_config.__dict__),
            speed_config=dict(self.speed_config.__dict__),
            n_members=self.n_members,
        )
        return settings, arrays

    @classmethod
    def from_json(cls, st: dict[str, Any], arrays: dict[str, np.ndarray]) -> HybridState:
        """Inverse of :meth:`to_json` (shapes checked against the configurations).

        Raises
        ------
        ValueError, KeyError
            On a malformed state.
        """
        cfg, scfg = MapConfig(**st["map_config"]), SpeedConfig(**st["speed_config"])
        n = int(st["n_members"])
        net = mlp(jax.random.key(0), 3, 2, cfg.width, cfg.depth, 0.0)
        skeleton = {
            "L": jnp.zeros((2, 3)),
            "s": jnp.zeros(2),
            "nn": eqx.filter(net, eqx.is_array),
            "mu0": jnp.asarray(0.0),
            "alpha": jnp.asarray(0.0),
        }
        map_params = _unflatten(stack([skeleton] * n), arrays, "map")
        speed_params = _unflatten(
            stack([init_speed_params(jax.random.key(0), scfg)] * n), arrays, "speed"
        )
        others = tuple(int(i) for i in st["others"])
        return cls(
            map_config=cfg,
            speed_config=scfg,
            map_params=map_params,
            speed_params=speed_params,
            observation=[ObservationModel.from_arrays(arrays, f"obs{s}_") for s in range(n)]
            if others
            else [],
            plane=(int(st["plane"][0]), int(st["plane"][1])),
            others=others,
            mu_c=float(st["mu_c"]),
            mu_s=float(st["mu_s"]),
            z_scale=np.asarray(arrays["z_scale"], dtype=float),
            white=_checked(arrays["white"], (2, 2)),
            direction=float(st["direction"]),
            q5=float(st["q5"]),
            a2_mode=str(st["a2_mode"]),
            omega_scale=float(st["omega_scale"]),
            signal_names=tuple(st["signal_names"]),
            param_name=str(st["param_name"]),
            param_units=str(st["param_units"]),
            signal_units=dict(st["signal_units"]),
            primary=int(st["primary"]),
        )


def states_to_json(
    states: list[HybridState], prefix: str
) -> tuple[list[dict[str, Any]], dict[str, np.ndarray]]:
    """Settings and arrays of several states; array names ``{prefix}{i}_{name}``."""
    settings, arrays = [], {}
    for i, state in enumerate(states):
        st, arr = state.to_json()
        settings.append(st)
        arrays.update({f"{prefix}{i}_{k}": v for k, v in arr.items()})
    return settings, arrays


def states_from_json(
    settings: list[dict[str, Any]], arrays: dict[str, np.ndarray], prefix: str
) -> list[HybridState]:
    """Inverse of :func:`states_to_json`."""
    out = []
    for i, st in enumerate(settings):
        head = f"{prefix}{i}_"
        own = {k[len(head) :]: v for k, v in arrays.items() if k.startswith(head)}
        out.append(HybridState.from_json(st, own))
    return out


def _checked(arr: np.ndarray, shape: tuple) -> np.ndarray:
    if tuple(arr.shape) != tuple(shape):
        raise ValueError(f"array of shape {arr.shape} where {tuple(shape)} was expected")
    return np.asarray(arr, dtype=float)


def _unflatten(skeleton: Any, arrays: dict[str, np.ndarray], prefix: str) -> Any:
    leaves, tdef = jax.tree_util.tree_flatten(skeleton)
    return jax.tree_util.tree_unflatten(
        tdef, [_checked(arrays[f"{prefix}_{j}"], leaf.shape) for j, leaf in enumerate(leaves)]
    )
