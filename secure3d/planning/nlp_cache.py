"""Built NLPs, cached by structure, and the table of transcriptions that build them.

A *transcription* turns a :class:`~secure3d.planning.problem.PlanningProblem` into a solver-ready
NLP (:class:`~secure3d.planning.collocation.TranscribedNLP`): IPOPT's collocation
(:mod:`secure3d.planning.collocation`) or fatrop's stage-wise form
(:mod:`secure3d.planning.fatrop_transcription`). Each registers itself in :data:`TRANSCRIPTIONS`
under its ``options.solver`` name when imported (the package imports both), so this module
imports neither, and neither imports the other to dispatch: adding a solver is one module and one
:func:`register_transcription` call.

:func:`nlp_key` says what determines an NLP's structure; :class:`NLPCache` keeps the built NLPs
(and the node kernels they share) by that key.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from secure3d.errors import ConfigError
from secure3d.planning.problem import Planner, Solver

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.kernels import NodeKernels
    from secure3d.planning.problem import PlanningProblem
    from secure3d.planning.transcribed import TranscribedNLP

__all__ = [
    "TRANSCRIPTIONS",
    "NLPCache",
    "Transcription",
    "family_identity",
    "model_identity",
    "nlp_key",
    "register_transcription",
    "transcription",
]


@dataclass(frozen=True)
class Transcription:
    """How one solver's NLP is built: ``kernels(problem)`` builds the per-node constraint Functions
    (shared by every NLP of the problem's shape), ``build(problem, planner, assignment, kernels)``
    the NLP for one look-back assignment."""

    build: Callable[..., TranscribedNLP]
    kernels: Callable[[PlanningProblem], NodeKernels]


#: Solver name (``PlannerOptions.solver``) -> its transcription.
TRANSCRIPTIONS: dict[str, Transcription] = {}


def register_transcription(
    solver: str, build: Callable[..., Any], kernels: Callable[[Any], Any]
) -> None:
    """Make ``solver``'s transcription available to :class:`NLPCache` (called once per module)."""
    TRANSCRIPTIONS[solver] = Transcription(build, kernels)


def transcription(solver: str) -> Transcription:
    """The transcription registered for ``solver``."""
    try:
        return TRANSCRIPTIONS[solver]
    except KeyError:
        raise ConfigError(
            f"solver: no transcription for {solver!r} (known: {sorted(TRANSCRIPTIONS)})"
        ) from None


def model_identity(model: object) -> tuple:
    """What makes two vehicle models interchangeable in an NLP (their frozen configuration)."""
    return (type(model).__name__, model.name, model.limits, float(model.body_radius), model.mount)


def family_identity(family: object) -> tuple:
    """What makes two reactive-set families interchangeable: class, model, controller, latency and,
    for fitted families, the coefficients' data file content."""
    coefs = [
        getattr(family, a)
        for a in ("centre_coef", "beta_coef", "gamma_coef", "eta_coef")
        if hasattr(family, a)
    ]
    digest = (
        hash(b"".join(np.asarray(c_, dtype=float).tobytes() for c_ in coefs)) if coefs else None
    )
    return (
        type(family).__name__,
        getattr(family, "kind", None),
        getattr(family, "controller_name", None),
        float(getattr(family, "latency", 0.0)),
        model_identity(family.model),
        digest,
    )


def nlp_key(problem: PlanningProblem, planner: str, assignment: tuple[int, ...]) -> tuple:
    """What determines the NLP's structure: the same key means the compiled NLP can be reused."""
    o = problem.options
    return (
        model_identity(problem.model),
        family_identity(problem.family),
        problem.frustum,
        planner,
        o.nodes,
        o.obstacle_slots,
        o.one_sided_duals and o.solver == Solver.IPOPT,
        o.collocation,
        o.margin,
        o.occlusion if planner == Planner.SECURE else False,
        o.interval_rows if planner == Planner.SECURE else False,
        o.effort_weight,
        o.solver,
        o.max_iter,
        o.time_limit,
        o.verbose,
        tuple(problem.bounds_lo),
        tuple(problem.bounds_hi),
        o.lookback_encoding if planner == Planner.SECURE else "",
        # the assignment is structure unless it is passed as a parameter (never for fatrop)
        tuple(assignment)
        if planner == Planner.SECURE
        and (o.solver == Solver.FATROP or o.lookback_encoding == "structure")
        else (),
    )


class NLPCache:
    """Least-recently-used cache of built NLPs, keyed by structure (see :func:`nlp_key`).

    The cache holds the model and family objects its keys refer to (by id), so those ids stay valid.
    A simulator keeps one cache for a whole flight; :func:`secure3d.plan` uses a shared default.
    """

    def __init__(self, max_size: int = 24) -> None:
        self.max_size = max_size
        self._items: OrderedDict[tuple, tuple[TranscribedNLP, object, object]] = OrderedDict()
        self._kernels: OrderedDict[tuple, tuple[NodeKernels, object, object]] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(
        self, problem: PlanningProblem, planner: str, assignment: tuple[int, ...]
    ) -> tuple[TranscribedNLP, bool]:
        """The NLP for this structure and whether it came from the cache."""
        key = nlp_key(problem, planner, assignment)
        item = self._items.get(key)
        if item is not None:
            self._items.move_to_end(key)
            self.hits += 1
            return item[0], True
        self.misses += 1
        tr = transcription(problem.options.solver)
        kkey = nlp_key(problem, "kernels", ())
        if kkey not in self._kernels:
            self._kernels[kkey] = (tr.kernels(problem), problem.model, problem.family)
            while len(self._kernels) > self.max_size:
                self._kernels.popitem(last=False)
        built = tr.build(problem, planner, assignment, self._kernels[kkey][0])
        self._items[key] = (built, problem.model, problem.family)
        while len(self._items) > self.max_size:
            self._items.popitem(last=False)
        return built, False

    def prepare(self, problem: PlanningProblem, planner: str) -> bool:
        """Compile ahead the NLP ``planner`` will solve for ``problem``'s structure, so that the
        first plan does not pay for it. Possible only when the structure does not depend on the
        look-back assignment (the baseline, or look-backs passed as parameters to IPOPT); returns
        whether the NLP is cached. Otherwise what every assignment's NLP shares is built (an NLP
        for one assignment)."""
        if planner not in tuple(Planner):
            raise ConfigError(f"planner: must be 'secure' or 'baseline', got {planner!r}")
        K = problem.options.nodes
        start_only, first_node = (-1,) * K, (0,) * K
        if nlp_key(problem, planner, start_only) != nlp_key(problem, planner, first_node):
            # One NLP per assignment, known only at plan time. Build one that ties nodes both to
            # the start region and to an earlier node: the node kernels, their derivatives and
            # their compiled libraries, which every assignment's NLP shares, are then ready (a
            # flight's first plan built them: 0.06-0.08 s of its 0.14 s build). Once per shape.
            if nlp_key(problem, "kernels", ()) not in self._kernels:
                self.get(problem, planner, start_only[: K // 2] + first_node[K // 2 :])
            return False
        self.get(problem, planner, start_only)
        return True

    def __len__(self) -> int:
        return len(self._items)
