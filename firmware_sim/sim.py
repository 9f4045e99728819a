"""The simulated chair as the bus sees it: plant, two drive nodes, the localizer.

:class:`ChairSim` owns simulation time (integer ns) and advances it one bench
step at a time: ten 1 kHz drive ticks (encoder sample, PID, voltage), each
followed by ``physics_substeps`` RK4 steps of the plant.  It routes decoded
payloads to the drive they address and collects the payloads due at a step
boundary; it never touches CAN (that is :mod:`firmware_sim.bench`), so unit
tests drive it with payload objects and synthetic time.

Fault seam: :meth:`ChairSim.add_tick_hook` registers a callable run at the
start of every drive tick with the time and the plant, where a fault model
(:mod:`firmware_sim.faults`) changes a :class:`~firmware_sim.plant.Wheel`'s
radius, offset, torque gain or slip.  A step that leaves the chair's state
non-finite raises :class:`FloatingPointError` (the bench ends the run cleanly).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import can

from dbc.codec import (
    BusVoltageCurrent,
    Codec,
    EncoderEstimates,
    Heartbeat,
    HostAuth,
    HostHeartbeat,
    Iq,
    Node,
    SetInputVelAuth,
    TruthContact,
    TruthPose,
    TruthTwist,
    TruthWheels,
)
from dbc.secoc import load_key
from firmware_sim.config import BenchConfig
from firmware_sim.drive import DriveNode, Out
from firmware_sim.localizer import Localizer
from firmware_sim.plant import Plant, wrap_angle

TickHook = Callable[[int, Plant], None]


def cyclic_periods_ns(codec: Codec) -> dict[type, int]:
    """Cycle times of the drives' cyclic frames and of the host's setpoint, from the DBC
    (left node's; both agree)."""
    out: dict[type, int] = {}
    for cls in (Heartbeat, EncoderEstimates, Iq, BusVoltageCurrent, SetInputVelAuth):
        ms = codec.cycle_time_ms(cls, Node.LEFT)
        if not ms:
            raise ValueError(f"DBC gives no cycle time for {cls.__name__}")
        out[cls] = int(ms) * 1_000_000
    return out


class ChairSim:
    """Plant + left/right :class:`DriveNode` + optional :class:`Localizer`, in lock-step."""

    def __init__(
        self,
        config: BenchConfig,
        *,
        seed: int = 0,
        initial_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
        codec: Codec | None = None,
    ) -> None:
        codec = codec or Codec.default()
        self.config = config
        x, y, heading = initial_pose
        self.plant = Plant(
            config.chair, config.motor, config.drive, x_m=x, y_m=y, heading_rad=heading
        )
        periods = cyclic_periods_ns(codec)
        for cls, period in periods.items():
            if period % config.step_ns:
                raise ValueError(
                    f"{cls.__name__} period {period} ns is not a multiple of the bench step"
                )
        # The drives' key: a start-up error if authentication is on and the file is missing.
        key = load_key(config.key_path) if config.drive.require_auth else None
        h = codec.contract_hash
        self.left = DriveNode(Node.LEFT, config, self.plant.left, periods, key=key, contract_hash=h)
        self.right = DriveNode(
            Node.RIGHT, config, self.plant.right, periods, key=key, contract_hash=h
        )
        self.drives: dict[Node, DriveNode] = {Node.LEFT: self.left, Node.RIGHT: self.right}
        self.localizer = (
            Localizer(config.localizer, config.localizer_period_ns, seed=seed)
            if config.localizer.enabled
            else None
        )
        self.now_ns = 0
        self.step_ns = config.step_ns
        self._tick_ns = config.tick_ns
        self._ticks = config.step_ns // config.tick_ns
        self._substeps = config.bench.physics_substeps
        self._h_s = config.tick_ns / 1e9 / self._substeps
        self._step_s = config.step_ns / 1e9
        self._hooks: list[TickHook] = []

    def add_tick_hook(self, hook: TickHook) -> None:
        """Run ``hook(t_ns, plant)`` at the start of every drive tick (fault models)."""
        self._hooks.append(hook)

    # ---------------------------------------------------------------- frames

    def handle(
        self, node: Node | None, payload: Any, out: Out, msg: can.Message | None = None
    ) -> bool:
        """Route a decoded payload to the drive ``node``; replies go to ``out``.

        ``msg`` is the received frame (its ID and bytes are what a MAC covers).  The host's
        heartbeat is a broadcast: both drives monitor it (Host_Timeout).  A Host_Auth PDU
        goes to the drive it names.
        """
        if type(payload) is HostHeartbeat:
            now = self.now_ns
            fed_l = self.left.on_host_heartbeat(payload, now)
            fed_r = self.right.on_host_heartbeat(payload, now)
            return fed_l or fed_r
        if type(payload) is HostAuth:
            target = (
                self.drives.get(Node(payload.target_node))
                if payload.target_node
                in (
                    Node.LEFT,
                    Node.RIGHT,
                )
                else None
            )
            if target is None:
                return False
            return target.handle(target.node, payload, self.now_ns, out, msg)
        drive = self.drives.get(node) if node is not None else None
        if drive is None:
            return False
        return drive.handle(node, payload, self.now_ns, out, msg)

    def emit_due(self, out: Out) -> None:
        """Append the drive and localizer frames due at the current time."""
        now = self.now_ns
        self.left.emit_due(now, out)
        self.right.emit_due(now, out)
        loc = self.localizer
        if loc is not None:
            p = self.plant
            loc.emit_due(now, p.x_m, p.y_m, p.heading_rad, out)

    def truth_pose(self) -> TruthPose:
        """The chair's true pose (heading wrapped) as a Truth_Pose payload."""
        p = self.plant
        return TruthPose(p.x_m, p.y_m, wrap_angle(p.heading_rad))

    def truth_twist(self) -> TruthTwist:
        """The chair's true body twist (m/s, rad/s) as a Truth_Twist payload."""
        p = self.plant
        return TruthTwist(p.v_mps, p.omega_radps)

    def truth_wheels(self) -> TruthWheels:
        """Each wheel's true rolling radius (m) and speed (rad/s) as a Truth_Wheels payload."""
        p = self.plant
        return TruthWheels(
            p.left.rolling_radius_m,
            p.right.rolling_radius_m,
            p.left.omega_radps,
            p.right.omega_radps,
        )

    def truth_contact(self) -> TruthContact:
        """Each wheel's slip ratio and contact radius (m) as a Truth_Contact payload."""
        p = self.plant
        return TruthContact(
            p.left.slip_ratio,
            p.right.slip_ratio,
            p.left.contact_radius_m,
            p.right.contact_radius_m,
        )

    # ------------------------------------------------------------- integration

    def advance(self) -> None:
        """Integrate one bench step: ``now_ns -> now_ns + step_ns``."""
        plant = self.plant
        l_control = self.left.control
        r_control = self.right.control
        l_update = self.left.encoder.update
        r_update = self.right.encoder.update
        l_wheel = plant.left
        r_wheel = plant.right
        hooks = self._hooks
        step = plant.step
        h = self._h_s
        sub = self._substeps
        tick = self._tick_ns
        now = self.now_ns
        for _ in range(self._ticks):
            if hooks:
                for hook in hooks:
                    hook(now, plant)
            l_control(now)
            r_control(now)
            if sub == 1:
                step(h)
            else:
                for _ in range(sub):
                    step(h)
            now += tick
            l_update(l_wheel.angle_rad)
            r_update(r_wheel.angle_rad)
        self.now_ns = now
        if not (
            math.isfinite(plant.x_m + plant.y_m + plant.heading_rad)
            and math.isfinite(l_wheel.omega_radps + r_wheel.omega_radps)
            and math.isfinite(l_wheel.current_a + r_wheel.current_a)
        ):
            raise FloatingPointError(f"the chair's state diverged at t={now / 1e9:.3f} s")
        self.left.housekeeping(self._step_s)
        self.right.housekeeping(self._step_s)
