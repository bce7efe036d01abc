"""Secure minimum-time planning (the paper's eq. NLP), the baseline planner and the certificate.

- :func:`plan` / :func:`plan_problem`: build, guess, solve (IPOPT or fatrop), certify;
- :class:`PlanningProblem`, :class:`PlannerOptions`: *what* is solved;
- :mod:`.collocation` (IPOPT) and :mod:`.fatrop_transcription`: *how* it is transcribed, both over
  the node kernels of :mod:`.kernels`; :mod:`.constraints`: the constraint families;
- :func:`certify`: the independent safety check (shares no constraint code with the NLP).
"""

# The two transcriptions register themselves in nlp_cache.TRANSCRIPTIONS when imported.
from secure3d.planning import collocation, fatrop_transcription  # noqa: F401
from secure3d.planning.certificate import CertificateSettings, certify
from secure3d.planning.nlp_cache import NLPCache
from secure3d.planning.problem import (
    Planner,
    PlannerOptions,
    PlanningProblem,
    Solver,
    problem_from_scenario,
)
from secure3d.planning.result import Certificate, PlanResult, PlanStatus, Violation
from secure3d.planning.solve import plan, plan_problem

__all__ = [
    "Certificate",
    "CertificateSettings",
    "NLPCache",
    "PlanResult",
    "PlanStatus",
    "Planner",
    "PlannerOptions",
    "PlanningProblem",
    "Solver",
    "Violation",
    "certify",
    "plan",
    "plan_problem",
    "problem_from_scenario",
]
