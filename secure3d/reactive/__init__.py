"""Reactive controllers pi(x, O) and their reactive sets S_r(x) (paper Definition 1, eq.
ReactEllipse).

- :mod:`.controllers`: :class:`~.controllers.BrakingController` (every model) and
  :class:`~.controllers.MPCReactiveController` (the paper's MPC, point mass), with vectorised
  rollouts;
- :mod:`.reactive_set`: ellipsoid families (closed form and fitted) and
  :func:`~.reactive_set.check_containment`;
- :mod:`.family_store`: :func:`~.family_store.family_for` (what the planner calls): the shipped
  family, a cached one, or one fitted on demand for any limits and checked before use;
- :mod:`.fitting`: fitting families to simulated manoeuvres (``benchmarks/fit_reactive_sets.py``);
- :mod:`.one_d`: the paper's 1D double-integrator example.

Submodules are imported explicitly (``from secure3d.reactive.family_store import family_for``) so
that importing the package stays cheap.
"""
