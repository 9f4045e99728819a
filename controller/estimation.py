"""Pose estimation as the loop sees it: odometry from the drives' encoder estimates, fused
with the localizer's fixes by the EKF (:mod:`controller.pose_ekf`), and the fault
diagnosis (:mod:`controller.diagnosis`).

:class:`Estimation` is fed from the :class:`~controller.link.DriveLink` once per tick.
Odometry integrates whenever either drive reported a new position; a fix received
while arming re-initialises the estimate (the chair may not stand where the route
starts), afterwards fixes are fused by the EKF.  The filter bank gets the same
encoder positions and fixes; after each fix its effective wheel radii replace the
odometry's, so that a diagnosed flat tire stops corrupting the pose estimate
(``[estimation] diagnosis_feedback``; off, the odometry keeps the nominal radius).
Sensor faults configured in ``[[estimation.perceived_flats]]`` alter the encoder positions
both see (:mod:`controller.sensor_faults`): the paper's flat tire as a sensor fault.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from controller.config import EstimationParams, GeometryParams
from controller.diagnosis import HYPOTHESIS_NAMES, Diagnosis, DiagnosisParams, FaultBank
from controller.link import DriveLink
from controller.odometry import Odometry
from controller.pose_ekf import EstimatorParams, PoseEstimator
from controller.sensor_faults import PerceivedEncoders
from controller.types import Pose, StateEstimate
from dbc.codec import Codec, HostDiagnosis, Hypothesis, Node, PoseFix

_HYP_NAMES = tuple(HYPOTHESIS_NAMES[h] for h in Hypothesis)


class Estimation:
    """The loop's pose estimation: odometry, the EKF and the fault bank, fed once per tick."""

    def __init__(
        self,
        geometry: GeometryParams,
        start_pose: Pose,
        params: EstimatorParams | None = None,
        diagnosis: DiagnosisParams | None = None,
        settings: EstimationParams | None = None,
        codec: Codec | None = None,
    ) -> None:
        b, r = geometry.half_track_m, geometry.wheel_radius_m
        # Host_Diagnosis' ranges (the contract's, ``codec``'s): saturated before encoding
        codec = codec if codec is not None else Codec.default()
        self._wire = tuple(
            codec.signal_scale(HostDiagnosis, f, Node.HOST)[1:]
            for f in ("probability", "radius_left_m", "radius_right_m")
        )
        self.settings = settings = settings or EstimationParams()
        self.perceived = PerceivedEncoders(settings.perceived_flats, r)
        self.odometry = Odometry(b, r, r, pose=start_pose)
        if not settings.wheel_scale_state:
            params = dataclasses.replace(
                params or EstimatorParams(), scale_initial_std=0.0, scale_drift_std_per_sqrt_m=0.0
            )
        self.ekf = PoseEstimator(b, params, pose=start_pose, t_s=0.0)
        self.bank = FaultBank(b, r, diagnosis, pose=start_pose)
        self._diagnosis = self.bank.diagnosis()
        self._msgs = (0, 0)
        self._t_s = 0.0
        #: Wheel travel (m, left and right) of the odometry interval the latest update()
        #: predicted with, as the EKF believes it (its differential scale applied); (0, 0)
        #: if it predicted nothing.  The node judges the estimate's
        #: per-tick step beyond what this travel moves it (NodeStats.estimate_step_max_m).
        self.tick_travel_m = (0.0, 0.0)

    def update(self, link: DriveLink, t_ns: int) -> None:
        """Integrate the drives' latest positions if either changed since the last tick."""
        self._t_s = t_s = t_ns * 1e-9
        self.tick_travel_m = (0.0, 0.0)
        left, right = link.drives[Node.LEFT], link.drives[Node.RIGHT]
        msgs = (left.encoder_msgs, right.encoder_msgs)
        if msgs == self._msgs or not (left.encoder_msgs and right.encoder_msgs):
            return
        self._msgs = msgs
        pos_l, pos_r = self.perceived.positions(left.pos_rev, right.pos_rev, t_s)
        self.bank.predict(pos_l, pos_r)
        inc = self.odometry.update(pos_l, pos_r, t_s)
        if inc is not None and self.ekf.predict(inc, t_s):
            self.tick_travel_m = self.ekf.travel_m

    def fuse_fix(self, fix: PoseFix, *, initialise: bool) -> bool:
        """Use a localizer fix: as the initial pose while arming, as a measurement afterwards."""
        if initialise:
            pose = Pose(fix.x_m, fix.y_m, fix.heading_rad)
            p = self.ekf.params
            self.ekf.reset(
                pose, self._t_s, pos_std_m=p.fix_pos_std_m, heading_std_rad=p.fix_heading_std_rad
            )
            self.odometry.reset_pose(pose)
            self.bank.reset(pose)
            return True
        if self.bank.correct(fix.x_m, fix.y_m, fix.heading_rad):
            self._diagnosis = d = self.bank.diagnosis()
            if self.settings.diagnosis_feedback:
                self.set_radii(d.radius_left_m, d.radius_right_m)
        return self.ekf.correct(fix)

    def set_radii(self, r_left_m: float, r_right_m: float) -> bool:
        """Believe new effective rolling radii (e.g. from the fault diagnosis); the EKF's
        differential scale is rebased so that the travels it believes do not jump."""
        odo = self.odometry
        old_l, old_r = odo.r_left_m, odo.r_right_m
        if not odo.set_radii(r_left_m, r_right_m):
            return False
        if (odo.r_left_m, odo.r_right_m) != (old_l, old_r):
            self.ekf.rebase_scale(odo.r_left_m / old_l, odo.r_right_m / old_r)
        return True

    def estimate(self) -> StateEstimate:
        """The EKF's state estimate at the time of the latest update."""
        return self.ekf.estimate(self._t_s)

    @property
    def diagnosis(self) -> Diagnosis:
        """The filter bank's latest verdict (after the latest fix)."""
        return self._diagnosis

    def diagnosis_frame(self) -> HostDiagnosis:
        """Host_Diagnosis for the bus, values saturated into the frame's ranges."""
        d = self._diagnosis
        p, rl, rr = (
            min(max(x if math.isfinite(x) else 0.0, lo), hi)
            for x, (lo, hi) in zip(
                (d.probability, d.radius_left_m, d.radius_right_m), self._wire, strict=True
            )
        )
        return HostDiagnosis(d.hypothesis, p, rl, rr)

    def counters(self) -> dict[str, int]:
        """The estimator's health over the run (the summary's ``estimator``): fixes the EKF
        fused, gated out and recovered from, corrections that held its differential scale at
        ``scale_max``, and the inputs it and the fault bank refused (non-finite) or rolled back
        (numerically failed)."""
        ekf, bank = self.ekf, self.bank
        return {
            "fixes_fused": ekf.fixes_accepted,
            "fixes_gated": ekf.fixes_rejected,
            "gate_recoveries": ekf.gate_recoveries,
            "wheel_scale_held": ekf.scale_held,
            "nonfinite_inputs": ekf.nonfinite_count
            + bank.nonfinite_count
            + self.odometry.nonfinite_count,
            "numerical_failures": ekf.numerical_failures + bank.numerical_failures,
            "bank_fixes_used": bank.fixes_used,
            "bank_fixes_outlier": bank.fixes_outlier,
        }

    def diagnosis_record(self) -> dict[str, Any]:
        """The diagnosis for the controller's telemetry record, with the EKF's differential
        wheel scale (``wheel_scale``, :attr:`PoseEstimator.scale`)."""
        d = self._diagnosis
        return {
            "hypothesis": d.name,
            "probability": d.probability,
            "p": {n: v for n, v in zip(_HYP_NAMES, d.probabilities, strict=True)},
            "radius_left": d.radius_left_m,
            "radius_right": d.radius_right_m,
            "wheel_scale": self.ekf.scale,
        }
