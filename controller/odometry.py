"""Wheel odometry from the drives' encoder position estimates.

This module owns dead reckoning: turning the two drives' ``Get_Encoder_Estimates`` positions
(wheel revolutions, as float on the wire) into wheel travel and an integrated pose.

* travel per wheel is ``Δrev · 2π · r`` with the *current* radius estimate of that wheel
  (:meth:`Odometry.set_radii` -- the fault diagnosis updates it when it believes a tire is
  flat);
* the pose is integrated with the exact arc of a differential drive (constant wheel speeds over
  the interval), :func:`arc_step`, which the pose EKF uses as its motion model too;
* bad input never raises: the first sample only sets the baseline; a non-finite position is
  ignored and counted (the next good sample integrates the whole travel since the last one); a
  jump beyond physics (a drive rebooted or its position was reset) is counted and reported in
  :attr:`Odometry.last_rejection`, the baseline is re-taken and that interval is not
  integrated.

Pure computation: no bus, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.kernels import arc_step as arc_step  # (compiled where built so)
from controller.kinematics import TWO_PI
from controller.types import Pose, wrap_angle
from dbc.runtime.frozen import fast_init


@fast_init
@dataclass(frozen=True, slots=True)
class OdometryIncrement:
    """Wheel travel and pose change over one integrated interval."""

    ds_left_m: float
    ds_right_m: float
    ds_m: float  # travel of the axle midpoint along the arc
    dphi_rad: float
    dx_body_m: float  # chord in the body frame at the start of the interval
    dy_body_m: float
    dx_m: float  # chord in the world frame
    dy_m: float
    dt_s: float  # interval covered (nan if the caller gave no times)


class Odometry:
    """Dead reckoning of the axle midpoint from the two wheels' positions (rev).

    ``max_wheel_speed_mps`` bounds what physics allows between two samples: a wheel that moves
    more than ``max_wheel_speed_mps · dt + jump_margin_m`` (or ``max_step_m`` when no time is
    given) is treated as a position reset, not as motion.
    """

    def __init__(
        self,
        half_track_m: float,
        r_left_m: float,
        r_right_m: float,
        *,
        max_wheel_speed_mps: float = 4.0,
        jump_margin_m: float = 0.05,
        max_step_m: float = 0.5,
        pose: Pose | None = None,
    ) -> None:
        if not (math.isfinite(half_track_m) and half_track_m > 0.0):
            raise ValueError(f"half_track_m must be positive and finite, got {half_track_m}")
        self.rejected_radii_count = 0
        if not self.set_radii(r_left_m, r_right_m):
            raise ValueError(
                f"wheel radii must be positive and finite, got {r_left_m}, {r_right_m}"
            )
        self.half_track_m = half_track_m
        self.max_wheel_speed_mps = max_wheel_speed_mps
        self.jump_margin_m = jump_margin_m
        self.max_step_m = max_step_m
        p = pose or Pose(0.0, 0.0, 0.0)
        self.x_m, self.y_m, self.heading_rad = p.x_m, p.y_m, wrap_angle(p.heading_rad)
        self._last_left: float | None = None
        self._last_right: float | None = None
        self._last_t: float | None = None
        self.updates = 0  # integrated intervals
        self.nonfinite_count = 0
        self.jump_count = 0
        self.last_rejection: str | None = None
        self.distance_m = 0.0  # total travel of the axle midpoint (absolute)

    # -- configuration at tick time --------------------------------------------------------

    def set_radii(self, r_left_m: float, r_right_m: float) -> bool:
        """Use new rolling-radius estimates from now on; non-finite or ≤ 0 is ignored (False)."""
        ok = all(math.isfinite(r) and 0.0 < r < 10.0 for r in (r_left_m, r_right_m))
        if ok:
            self.r_left_m, self.r_right_m = float(r_left_m), float(r_right_m)
        else:
            self.rejected_radii_count += 1
        return ok

    def reset_pose(self, pose: Pose) -> None:
        """Set the integrated pose (the wheel baselines are kept)."""
        self.x_m, self.y_m, self.heading_rad = pose.x_m, pose.y_m, wrap_angle(pose.heading_rad)

    @property
    def pose(self) -> Pose:
        """The integrated pose of the axle midpoint."""
        return Pose(self.x_m, self.y_m, self.heading_rad)

    @property
    def has_baseline(self) -> bool:
        """Whether wheel positions were taken that the next update integrates from."""
        return self._last_left is not None

    # -- the tick --------------------------------------------------------------------------

    def update(
        self, pos_left_rev: float, pos_right_rev: float, t_s: float | None = None
    ) -> OdometryIncrement | None:
        """Integrate the travel since the previous sample; None if nothing was integrated.

        ``t_s`` (optional) is the time of the sample; it sharpens the jump test and gives the
        increment its ``dt_s``.
        """
        pl, pr = float(pos_left_rev), float(pos_right_rev)
        if not (math.isfinite(pl) and math.isfinite(pr)):
            self.nonfinite_count += 1
            self.last_rejection = "nonfinite"
            return None
        if t_s is not None and not math.isfinite(t_s):
            t_s = None
        last_l, last_r = self._last_left, self._last_right
        if last_l is None or last_r is None:
            self._rebase(pl, pr, t_s)
            return None
        ds_l = (pl - last_l) * TWO_PI * self.r_left_m
        ds_r = (pr - last_r) * TWO_PI * self.r_right_m
        dt = t_s - self._last_t if (t_s is not None and self._last_t is not None) else math.nan
        if dt == dt and dt > 0.0:
            limit = self.max_wheel_speed_mps * dt + self.jump_margin_m
        else:
            limit = self.max_step_m
        if abs(ds_l) > limit or abs(ds_r) > limit:
            self.jump_count += 1
            side = "left" if abs(ds_l) > limit else "right"
            self.last_rejection = (
                f"jump: {side} wheel moved {ds_l if side == 'left' else ds_r:+.3f} m "
                f"(limit {limit:.3f} m); baseline re-taken"
            )
            self._rebase(pl, pr, t_s)
            return None
        phi0 = self.heading_rad
        self.x_m, self.y_m, self.heading_rad, chord, dphi = arc_step(
            self.x_m, self.y_m, phi0, ds_l, ds_r, self.half_track_m
        )
        self._rebase(pl, pr, t_s)
        ds = 0.5 * (ds_l + ds_r)
        self.distance_m += abs(ds)
        self.updates += 1
        half = 0.5 * dphi
        c, s = math.cos(phi0 + half), math.sin(phi0 + half)
        return OdometryIncrement(
            ds_left_m=ds_l,
            ds_right_m=ds_r,
            ds_m=ds,
            dphi_rad=dphi,
            dx_body_m=chord * math.cos(half),
            dy_body_m=chord * math.sin(half),
            dx_m=chord * c,
            dy_m=chord * s,
            dt_s=dt,
        )

    def _rebase(self, pl: float, pr: float, t_s: float | None) -> None:
        self._last_left, self._last_right = pl, pr
        if t_s is not None:
            self._last_t = t_s
