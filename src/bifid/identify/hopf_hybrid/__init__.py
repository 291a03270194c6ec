r"""Hybrid normal-form + neural-network models of Hopf systems (thesis ch. 5).

A normal-form-like model fixes the bifurcation structure; learned maps make it match the
measured limit cycles, stable **and** unstable:

.. math::

    \dot r = (\mu - \mu_0) r + a_2 r^3 - q_5 r^5,\qquad \dot\theta = \Omega(r, \theta, \mu)
    \qquad\text{(eq. 5.3)}

    (\hat z_1, \hat z_2) = \mathbf U_{12}(u_1, u_2, \mu) = T_L(u, \mu) + T_s
        + \mathrm{NN}_{\Theta_U}(u, \mu)\qquad\text{(eqs. 5.8–5.9)}

    \Omega = \omega_0 + \mathrm{NN}_{\Theta_\Omega}(r, \mu)^{\mathsf T}[1, \cos\theta, \dots,
        \sin n\theta]\qquad\text{(eq. 5.10)}

and the other observed signals :math:`z_3 \dots z_m` by regression on :math:`(u_1, u_2, \mu)`
(§5.3.1). The Hopf point is :math:`\mu_0`, the fold of cycles :math:`\mu_0 - a_2^2/4`
(subcritical with quintic term), and the cycle radii are closed-form.

The pipeline, one module per step: :mod:`._prepare` (records → polar Fourier representation,
eqs. 5.4–5.6, :mod:`._polar`), :mod:`._train` (the map, §5.3.4: :math:`T_L, T_s` then the
network with :math:`\mu_0, a_2`, :mod:`._map`, :mod:`._optim`; the other signals,
:mod:`._observe`), :mod:`._speed_stage` (:math:`\Omega` from phase-matched orbits, eqs.
5.12–5.13, :mod:`._speed`), then the fitted :class:`~._state.HybridState` read by
:mod:`._cycles` and :mod:`._diagram`. Beyond the thesis, the L2 weight of the network and the
stopping iteration are chosen by leave-one-orbit-out cross-validation, an ensemble over seeds
gives a spread of the predicted diagram, and :mod:`._cv` reports the held-out error of every
orbit.

Example
-------
>>> model = HopfHybridModel(n_ensemble=3).fit("lcos.nc")            # doctest: +SKIP
>>> model.hopf_point()["param"], model.cycle_fold()["param"]       # doctest: +SKIP
"""

from bifid.identify.hopf_hybrid._figures import portraits_figure, series_figure
from bifid.identify.hopf_hybrid._model import HopfHybridModel

__all__ = ["HopfHybridModel", "portraits_figure", "series_figure"]
