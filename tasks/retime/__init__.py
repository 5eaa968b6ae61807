"""Physics-based motion retiming (design §8, MPS06 §3.1-3.6), one module per job.

* :mod:`.dynamics` — body model and path dynamics τ = a p̈ + b ṗ² + c (MPS06 §3.1);
* :mod:`.contacts` — foot contacts and friction-pyramid force bases (MPS06 §3.2);
* :mod:`.polygons` — original forces, torque limits and feasible (p̈, ṗ²) polygons by LPs (MPS06 §3.3);
* :mod:`.objective` — the fan-baked objective of MPS06 Eqn. 14 and its compiled kernels (§3.4, §3.6);
* :mod:`.spline` — the monotone timing spline p(t) and its L-BFGS-B optimizer (MPS06 §3.5-3.6);
* :mod:`.pipeline` — :func:`prepare` and :func:`retime_plan` end to end, under :class:`RetimeParams`
  (``tasks/params/retime.py``: its groups :class:`ContactParams`, :class:`PolygonParams` and
  :class:`SplineParams` are what the modules above take);
* :mod:`.reachable` — the shortest timing inside every polygon (TOPP-RA reachability on the path);
* :mod:`.path_timing` — a timing of a requested duration built on the source frames from those profiles;
* :mod:`.report` — flights, contact phases, feasibility and the shortest reachable duration.

The names below are the public API used by the flows and the benchmarks.
"""

from motionweb.tasks.params.retime import ContactParams, PolygonParams, RetimeParams, SplineParams
from motionweb.tasks.retime.errors import RetimeError
from motionweb.tasks.retime.pipeline import (
    RetimePlan,
    clip_contacts,
    prepare,
    retime_plan,
)
from motionweb.tasks.retime.report import (
    flight_intervals,
    inner_flights,
    phase_times,
    report,
    shortest_duration,
)
from motionweb.tasks.retime.spline import RetimeResult

__all__ = ["ContactParams", "PolygonParams", "RetimeError", "RetimeParams", "RetimePlan", "RetimeResult", "SplineParams",
           "clip_contacts", "flight_intervals", "inner_flights", "phase_times", "prepare", "report", "retime_plan",
           "shortest_duration"]
