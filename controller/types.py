"""Value types shared by the controller's parts, and the seams between them.

Conventions (used everywhere in ``controller/``):

* world frame ``xOy``, heading ``phi`` counter-clockwise from +x, wrapped to (-pi, pi];
* the chair's reference point is the axle midpoint P0 (the paper's Fig. 2);
* tracking errors follow the paper's Eq. (errorvector): the *actual* pose minus the
  *desired* one, rotated into the desired frame::

      x_e =  cos(phi_d)(x - x_d) + sin(phi_d)(y - y_d)     (along the path, + = ahead)
      y_e = -sin(phi_d)(x - x_d) + cos(phi_d)(y - y_d)     (left of the path = +)
      phi_e = wrap(phi - phi_d)

Controllers never read a clock and do no I/O: time and period are passed in.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar, Protocol, runtime_checkable

from controller.kernels import wrap_angle as wrap_angle
from dbc.runtime.frozen import fast_init

# wrap_angle(a): an angle wrapped to (-pi, pi]; NaN for a non-finite one (math.fmod raises on
# an infinity, and nothing may raise at tick time).  Called several times every tick, so it is
# controller.kernels' (compiled where the package was built so, the same bits either way).


@fast_init
@dataclass(frozen=True, slots=True)
class Pose:
    """A planar pose: position in the world frame (m) and heading (rad)."""

    x_m: float
    y_m: float
    heading_rad: float


@fast_init
@dataclass(frozen=True, slots=True)
class ReferenceSample:
    """The virtual robot at time ``t_s``: pose, velocities and their derivatives."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    v_mps: float
    omega_radps: float
    a_mps2: float = 0.0  # dv_d/dt
    alpha_radps2: float = 0.0  # domega_d/dt
    curvature_1pm: float = 0.0
    s_m: float = 0.0  # arc length travelled along the path
    done: bool = False  # past the end of the route, at rest


@fast_init
@dataclass(frozen=True, slots=True)
class StateEstimate:
    """What the controller believes about the chair (never the bench's ground truth)."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    v_mps: float
    omega_radps: float
    valid: bool = True


@fast_init
@dataclass(frozen=True, slots=True)
class TwistCommand:
    """Body velocity command at the axle midpoint."""

    v_mps: float
    omega_radps: float


@dataclass(frozen=True, slots=True)
class DriveGains:
    """Velocity-loop gains a controller wants on the drives, pushed when arming.

    Units of the drive (ODrive semantics, wheel revolutions): motor N*m per wheel rev/s
    (P), per wheel rev (I), per wheel rev/s^2 (D), and the D filter cut-off in Hz.
    A controller that exposes ``drive_gains`` gets them on both drives.
    """

    vel_gain: float
    vel_integrator_gain: float
    vel_derivative_gain: float = 0.0
    derivative_cutoff_hz: float = 50.0


@fast_init
@dataclass(frozen=True, slots=True)
class TrackingError:
    """Actual minus desired pose in the desired frame: along (m), left (m), heading (rad)."""

    x_e_m: float
    y_e_m: float
    phi_e_rad: float


def tracking_error(x: float, y: float, phi: float, ref: ReferenceSample | Pose) -> TrackingError:
    """Paper convention (see module doc): actual minus desired, in the desired frame."""
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    dx, dy = x - ref.x_m, y - ref.y_m
    return TrackingError(c * dx + s * dy, -s * dx + c * dy, wrap_angle(phi - ref.heading_rad))


@runtime_checkable
class Trajectory(Protocol):
    """A time-parametrized reference, sampled by the loop and previewed by predictive controllers."""

    @property
    def duration_s(self) -> float:
        """Length of the reference in time, in s."""

    def sample(self, t_s: float) -> ReferenceSample:
        """The virtual robot at ``t_s`` (s since the start)."""


@runtime_checkable
class Controller(Protocol):
    """A trajectory-tracking law.  Pure computation: no clock, no bus, no logging.

    ``step`` must return a finite command for any finite input; the loop checks
    anyway and brakes if it does not.  ``internals`` exposes values worth logging
    (sliding surfaces, solver status ...), read after each step.  ``drive_gains`` are
    the velocity-loop gains the law wants on both drives when the node arms them, or None
    for the drives' own.

    Optional (not part of the checked shape; the node looks it up with
    ``getattr(law, "activity", None)``): ``activity(self) -> Mapping[str, int]``, the counts
    since the last ``reset()`` of named events of the law's own, e.g.
    ``"outside_boundary1"``, ``"regime_fragile"`` or ``"qp_fallback"``, each the number of
    steps in which it happened, and ``"ticks"``, the steps counted.  ``step`` increments them
    with plain int additions (it runs in the profiled tick); the node reads ``activity()``
    once, at the end of a run, into the controller's statistics (``law_activity``), and the
    run's summary gives each as a share of ``"ticks"`` (``law_activity_share``).  A law
    without it reports none.
    """

    name: ClassVar[str]
    drive_gains: DriveGains | None

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Start over from ``estimate`` at ``t_s`` (s): clear the law's state."""

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        """The twist to command at ``t_s`` for ``ref`` given ``est``, ``dt_s`` s after the last."""

    def internals(self) -> Mapping[str, float]:
        """The last step's values worth logging, by name."""
