"""Pose estimation as the loop sees it: odometry from the drives' encoder estimates, fused
with the localizer's fixes by the EKF (:mod:`controller.estimator`).

:class:`Estimation` is fed from the :class:`~controller.link.DriveLink` once per tick.
Odometry integrates whenever either drive reported a new position; a fix received
while arming re-initialises the estimate (the chair may not stand where the route
starts), afterwards fixes are fused by the EKF.
"""

from __future__ import annotations

from controller.config import GeometryParams
from controller.estimator import EstimatorParams, PoseEstimator
from controller.link import DriveLink
from controller.odometry import Odometry
from controller.types import Pose, StateEstimate
from dbc.codec import Node, PoseFix


class Estimation:
    def __init__(
        self, geometry: GeometryParams, start_pose: Pose, params: EstimatorParams | None = None
    ) -> None:
        b, r = geometry.half_track_m, geometry.wheel_radius_m
        self.odometry = Odometry(b, r, r, pose=start_pose)
        self.ekf = PoseEstimator(b, params, pose=start_pose, t_s=0.0)
        self._msgs = (0, 0)
        self._t_s = 0.0

    def update(self, link: DriveLink, t_ns: int) -> None:
        """Integrate the drives' latest positions if either changed since the last tick."""
        self._t_s = t_s = t_ns * 1e-9
        left, right = link.drives[Node.LEFT], link.drives[Node.RIGHT]
        msgs = (left.encoder_msgs, right.encoder_msgs)
        if msgs == self._msgs or not (left.encoder_msgs and right.encoder_msgs):
            return
        self._msgs = msgs
        inc = self.odometry.update(left.pos_rev, right.pos_rev, t_s)
        if inc is not None:
            self.ekf.predict(inc, t_s)

    def fuse_fix(self, fix: PoseFix, *, initialise: bool) -> bool:
        """Use a localizer fix: as the initial pose while arming, as a measurement afterwards."""
        if initialise:
            pose = Pose(fix.x_m, fix.y_m, fix.heading_rad)
            p = self.ekf.params
            self.ekf.reset(
                pose, self._t_s, pos_std_m=p.fix_pos_std_m, heading_std_rad=p.fix_heading_std_rad
            )
            self.odometry.reset_pose(pose)
            return True
        return self.ekf.correct(fix)

    def set_radii(self, r_left_m: float, r_right_m: float) -> bool:
        """Believe new effective rolling radii (e.g. from the fault diagnosis)."""
        return self.odometry.set_radii(r_left_m, r_right_m)

    def estimate(self) -> StateEstimate:
        return self.ekf.estimate(self._t_s)
