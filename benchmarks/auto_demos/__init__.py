"""AUTO-07p demos as bifid system files, with the reference values of AUTO's regression log.

Each module is a plain bifid system file (it calls :func:`bifid.systems.register`) and also
holds ``AUTO_RUNS``: the one-parameter runs of the demo and the special points and orbits
AUTO-07p prints for them. Source of every equation and number: AUTO-07p
(E. J. Doedel, B. E. Oldeman et al., https://github.com/auto-07p/auto-07p), commit
``44cc1c42a888179bdbd608a40613caee9cbc4675`` (2025-06-26): the right-hand sides from
``demos/<name>/<name>.f90`` (subroutine FUNC), starting values from STPNT, run constants
from ``demos/<name>/c.<name>*`` and ``<name>.auto``, and the printed special points from
the regression log ``test/hyper.all``. The equations are transcribed, no code is copied.

Run description (one dict per AUTO run of equilibria, with the orbit runs started at its
Hopf points):

``label``       what AUTO's run is
``param``       the continuation parameter (bifid name; AUTO's ``PAR(i)`` in the module)
``range``       ``(start, end)``: bifid's ``--range`` (the run starts at ``start``)
``set``         parameter values different from the system's defaults
``x0``          starting equilibrium (``--x0``), or None for the origin
``detect``      what AUTO detected on this run (``ILP``, ``ISP``): ``hopf``, ``fold``,
                ``branch_point``
``hopf``, ``folds``, ``branch_points``: parameter values as printed (6 significant digits)
``orbits``      one dict per orbit run, keyed by the Hopf point it starts at: ``detect``
                (``cycle_fold``, ``period_doubling``, ``torus``, ``branch_point``), ``stop``
                (AUTO's stopping values: ``param`` values crossed along the branch, ``period``
                reached; ``max_period`` where AUTO ran out of steps), ``cycle_folds``
                ``((param, period), ...)``, ``branch_points`` (params), ``points``
                ``((param, period), ...)`` printed orbits, ``homoclinic``
                ``(param, period)`` when AUTO stopped at a large period.
"""
