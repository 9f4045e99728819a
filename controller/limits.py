"""Command shaping between a tracking law and the wheels.

Order of operations (each step counted when it changes the command):

1. box limits on v (forward / reverse separately) and omega;
2. wheel saturation of the target that preserves curvature: if a wheel would exceed
   ``wheel_max``, v and omega are scaled by the same factor, so the chair slows
   down on its intended arc instead of turning onto another one;
3. rate limits: speed-magnitude increase limited by ``accel_max``, decrease by
   ``decel_max``, acceleration change by ``jerk_max`` (with a braking cap so that the
   jerk limit never overshoots a fixed target, while a moving target is followed
   at its own rate; the box of step 1 wins over the jerk limit); omega change limited by
   ``alpha_max``;
4. the same wheel saturation again, for the transient mix of old and new command.

The result carries the wheel speeds of the command it sends (rad/s), computed once with
step 4's check: the node encodes them without converting the twist again.  The input must
be finite: the node stops (NON_FINITE) on a non-finite law output before it gets here, and
guards the wheel speeds once more before encoding.  Nothing here raises.

:class:`RateLimitMeter` measures, law-agnostically, how often the twist a law returns sits
at (or beyond) a limit of the envelope, before this shaping: what each run's summary reports
as ``rate_limit_share``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from controller.config import LimitParams
from controller.kernels import limit_step
from controller.kinematics import rim_speeds
from controller.types import TwistCommand
from dbc.runtime.frozen import fast_init


@fast_init
@dataclass(frozen=True, slots=True)
class LimitedCommand:
    """A command as the node sends it: the twist and its wheels' angular speeds (rad/s)."""

    v_mps: float
    omega_radps: float
    left_radps: float
    right_radps: float

    @classmethod
    def from_twist(
        cls, v_mps: float, omega_radps: float, half_track_m: float, wheel_radius_m: float
    ) -> LimitedCommand:
        """The twist with its wheel speeds (paper Eq. wheelscmds), unshaped."""
        left_mps, right_mps = rim_speeds(v_mps, omega_radps, half_track_m)
        return cls(v_mps, omega_radps, left_mps / wheel_radius_m, right_mps / wheel_radius_m)


#: Both wheels at rest.
STOP = LimitedCommand(0.0, 0.0, 0.0, 0.0)


@dataclass
class LimiterCounters:
    """How often each shaping step changed the command: box, rate and wheel limits."""

    box: int = 0
    rate: int = 0
    wheel: int = 0


@dataclass
class CommandLimiter:
    """Shapes a law's twist into the chair's limits (module doc), from its previous output."""

    limits: LimitParams
    half_track_m: float
    wheel_radius_m: float
    v_mps: float = 0.0
    a_mps2: float = 0.0
    omega_radps: float = 0.0
    counters: LimiterCounters = field(default_factory=LimiterCounters)
    _vb_prev: float = 0.0

    def __post_init__(self) -> None:
        lim = self.limits
        self._limits = (
            lim.v_max_mps,
            lim.v_reverse_max_mps,
            lim.omega_max_radps,
            lim.wheel_max_radps,
            lim.jerk_max_mps3,
            lim.accel_max_mps2,
            lim.decel_max_mps2,
            lim.alpha_max_radps2,
        )

    def reset(self, v_mps: float = 0.0, omega_radps: float = 0.0) -> None:
        """Restart the shaping from the twist ``(v_mps, omega_radps)`` at zero acceleration."""
        self.v_mps, self.a_mps2, self.omega_radps = v_mps, 0.0, omega_radps
        self._vb_prev = v_mps

    def apply(self, cmd: TwistCommand, dt_s: float) -> LimitedCommand:
        """Shape ``cmd`` (finite) given the previous output; returns the command to send."""
        # the steps below, in floats (controller.kernels.limit_step, compiled where the
        # package was built so; the same operations in the same order):
        # 1. box limits;
        # 2. wheel saturation of the target: scale v and omega together (same curvature);
        # 3. rate limits on v: the acceleration bound depends on whether |v| grows.
        #    Approaching a target, the acceleration relative to the target's own rate a_t must
        #    be one the jerk limit can still bring to zero by the time the gap dv is closed:
        #    (a - a_t)^2/(2j) + |a - a_t| h/2 <= |dv| in discrete time.  A fixed target
        #    (a_t = 0) is reached without overshoot; a ramp is followed without steady lag.
        #    The jerk-limited acceleration never carries v across the target, nor out of the
        #    box (a target that turns back, dv < 0 while a > 0); omega's rate is bounded;
        # 4. a rate-limited mix of the old and the new command may still exceed a wheel
        #    limit: scaled again; the wheel speeds of this check are the ones sent.
        v, a, w, vb, left, right, box, wheel, rate = limit_step(
            cmd.v_mps,
            cmd.omega_radps,
            dt_s,
            (self.v_mps, self.a_mps2, self.omega_radps, self._vb_prev),
            self._limits,
            self.half_track_m,
            self.wheel_radius_m,
        )
        c = self.counters
        c.box += box
        c.wheel += wheel
        c.rate += rate
        self.v_mps, self.a_mps2, self.omega_radps, self._vb_prev = v, a, w, vb
        return LimitedCommand(v, w, left, right)

    def stop_step(self, dt_s: float, decel_mps2: float) -> LimitedCommand:
        """One step of a coordinated stop: v and omega shrink together (no yaw kick)."""
        v0, w0 = self.v_mps, self.omega_radps
        if v0 == 0.0 and w0 == 0.0:
            return STOP
        left_mps, right_mps = rim_speeds(v0, w0, self.half_track_m)
        rim = max(abs(left_mps), abs(right_mps))  # fastest rim speed, m/s
        k = 0.0 if rim <= decel_mps2 * dt_s or rim == 0.0 else (rim - decel_mps2 * dt_s) / rim
        v, w = v0 * k, w0 * k
        self.a_mps2 = (v - v0) / dt_s if dt_s > 0.0 else 0.0
        self.v_mps, self.omega_radps = v, w
        return LimitedCommand.from_twist(v, w, self.half_track_m, self.wheel_radius_m)


#: The envelope's limits :class:`RateLimitMeter` counts, in the order reports show them.
RATE_LIMITS: tuple[str, ...] = ("accel", "turn_accel", "speed", "turn_rate", "jerk")
#: A command within this fraction of a limit is at it (float round-off of a law that
#: saturates exactly at the limit).
AT_LIMIT = 1.0 - 1e-3


class RateLimitMeter:
    """Counts the ticks whose law command is at a limit of the chair's envelope.

    Each tracking tick the node hands it the twist the law returned (before the limiter),
    and it compares that with the previous one (the command before tracking began: at
    rest), at the node's period ``dt_s``:

    * ``accel``: ``|dv|/dt`` at the acceleration limit when ``|v|`` grows, at the
      deceleration limit when it shrinks (the limiter's own choice of bound);
    * ``turn_accel``: ``|domega|/dt`` at the turn-rate change limit (``alpha_max``);
    * ``speed``: ``v`` at the forward or the reverse speed limit;
    * ``turn_rate``: ``|omega|`` at the turn-rate limit;
    * ``jerk``: the change of ``dv/dt`` from one tick to the next, per ``dt``, at the jerk
      limit.

    "At" is within :data:`AT_LIMIT` of the limit, or beyond it (the limiter then clips).
    Plain float comparisons and int increments: it runs inside the profiled tick.
    ``ticks`` counts the commands seen, the denominator of the shares.
    """

    __slots__ = (
        "_ddv",
        "_dv",
        "_dv_accel",
        "_dv_decel",
        "_dw",
        "_v",
        "_v_fwd",
        "_v_rev",
        "_w",
        "_w_max",
        "accel",
        "jerk",
        "speed",
        "ticks",
        "turn_accel",
        "turn_rate",
    )

    def __init__(self, limits: LimitParams, dt_s: float) -> None:
        self._dv_accel = limits.accel_max_mps2 * dt_s * AT_LIMIT
        self._dv_decel = limits.decel_max_mps2 * dt_s * AT_LIMIT
        self._dw = limits.alpha_max_radps2 * dt_s * AT_LIMIT
        self._ddv = limits.jerk_max_mps3 * dt_s * dt_s * AT_LIMIT
        self._v_fwd = limits.v_max_mps * AT_LIMIT
        self._v_rev = limits.v_reverse_max_mps * AT_LIMIT
        self._w_max = limits.omega_max_radps * AT_LIMIT
        self.reset()

    def reset(self) -> None:
        """Zero the counts; the previous command is rest."""
        self.ticks = self.accel = self.turn_accel = self.speed = self.turn_rate = self.jerk = 0
        self._v = self._w = self._dv = 0.0

    def observe(self, v_mps: float, omega_radps: float) -> None:
        """Count the law's command of this tick (finite)."""
        self.ticks += 1
        if v_mps >= self._v_fwd or (v_mps < 0.0 and -v_mps >= self._v_rev):
            self.speed += 1
        if abs(omega_radps) >= self._w_max:
            self.turn_rate += 1
        v0 = self._v
        dv = v_mps - v0
        growing = (v0 >= 0.0 and dv > 0.0) or (v0 <= 0.0 and dv < 0.0)
        if abs(dv) >= (self._dv_accel if growing else self._dv_decel):
            self.accel += 1
        if abs(omega_radps - self._w) >= self._dw:
            self.turn_accel += 1
        if abs(dv - self._dv) >= self._ddv:
            self.jerk += 1
        self._v, self._w, self._dv = v_mps, omega_radps, dv

    def counts(self) -> dict[str, int]:
        """``ticks`` and the count of each of :data:`RATE_LIMITS` (read once, after a run)."""
        return {
            "ticks": self.ticks,
            "accel": self.accel,
            "turn_accel": self.turn_accel,
            "speed": self.speed,
            "turn_rate": self.turn_rate,
            "jerk": self.jerk,
        }
