"""Where is the person heading? Bayesian goal inference from a person's track (issue 26).

The thesis's person model reacts to the cell a person is in. A guard that is there
first needs to know where they are *going*. This module keeps, for one person, a
belief over goals:

- each **restricted cell** of the task;
- **elsewhere**: anything else. Inside, "elsewhere" is several hypotheses whose sum is
  reported: walking to one of the other cells (``other_cells_as_goals``), to an exit
  point given by the caller (e.g. the door), or wandering with no goal at all.

**Motion model (Boltzmann-rational).** A person heading for goal g moves roughly
along a shortest path to it. On open floor the shortest path to a cell is the
straight line to its nearest point, so the cost-to-go C_g(x) is the distance from x
to the goal's rectangle (0 inside). For an observed displacement d from x (the
track's velocity times the time since the last observation), the *progress* toward g
is C_g(x) - C_g(x + d), and its likelihood is

    L_g(d) = (1 - lapse) * exp(beta * progress) / Z_g + lapse,

where Z_g averages exp(beta * progress) over every direction of a displacement of
the same length (so L is a density over directions, 1 on average) and ``lapse`` is
the share of steps taken with no regard to the goal (tracker noise, a sidestep).
``beta`` (``rationality_per_m``) is the rationality: 0 is a random walk, large is a
person who never deviates. Wandering has L = 1. Because the evidence between two
goals is beta * (difference of their progress), it accrues per metre walked, not per
observation: the same walk observed at 5 or 15 Hz gives about the same belief.

**Between observations** a person may change their mind: at rate
``switch_rate_per_s`` the goal is drawn afresh from the prior, so with no
observations (a camera outage, the track lost) the belief diffuses back to the
prior. A person **stopped** (speed under ``stop_speed_mps``) shows no direction, so
their belief only diffuses. A person **inside a restricted cell** has reached it:
that cell's belief is raised to at least ``inside_belief`` while they are in it; with
``renew_after_visit_m`` set, once they are that far out of it again, that goal is
reached and they draw a new one: the belief starts again from the prior (a visitor
walking out is not still heading for the cell they leave, and may head for another).

**Forecast.** Per restricted cell: the probability that it is the goal, the distance
to it (along the shortest path) and the predicted time to entry, distance / speed
(the speed no lower than ``eta_min_speed_mps``, so a person who stopped at the
border still counts as seconds away, not never).

How to feed it: one :class:`GoalInference` per person (or an :class:`IntentTracker`
keyed by track id), :meth:`GoalInference.update` with each track estimate
(:class:`TrackObservation`: time, map position, and the velocity or heading and speed
when the tracker has them), :meth:`GoalInference.predict` at a decision time with no
new observation. Both return an :class:`IntentEstimate`. Fitting ``beta`` and
``lapse`` to walks of known goals: :mod:`stack.planning.intent.fit`.

The parts: :mod:`~stack.planning.intent.model` (configuration, goals, the step
likelihood, displacements), :mod:`~stack.planning.intent.inference` (the belief),
:mod:`~stack.planning.intent.fit` (maximum likelihood, simulated walks).

Pure numpy; no ROS. Limits: the floor is open (no obstacles in the distances);
"elsewhere" is one aggregate for the caller.
"""

from stack.planning.intent import fit, inference, model
from stack.planning.intent.fit import *  # noqa: F403 (each part names its public API in __all__)
from stack.planning.intent.inference import *  # noqa: F403
from stack.planning.intent.model import *  # noqa: F403

__all__ = [*model.__all__, *inference.__all__, *fit.__all__]
