"""The drive's setpoint watchdog and host-heartbeat monitor, and what makes it refuse a setpoint.

One :class:`SetpointWatchdog` per axis, configured by Set_Watchdog (*ext*).  The drive's 1 kHz
tick (:meth:`firmware_sim.drive.DriveNode.control`) reads its timers, so it is compiled with
the other inner loops of the bench (:mod:`dbc.runtime.compiled`).
"""

from __future__ import annotations

#: Why a setpoint or heartbeat was not acted on (keys of
#: :attr:`firmware_sim.drive.DriveNode.ignored`); the authentication refusals are
#: :mod:`dbc.secoc`'s ``REJECT_*``.
REJECT_PLAIN = "plain_setpoint_auth_required"
REJECT_NOT_NEUTRAL = "not_neutral_after_arm"
REJECT_HOST_REPEATED = "host_heartbeat_repeated"


class SetpointWatchdog:
    """Setpoint watchdog and host-heartbeat monitor of one axis (configured by Set_Watchdog).

    ``timeout_ms == 0`` disables the setpoint watchdog, ``host_timeout_ms == 0`` the host
    monitor.  Both start timing when the axis arms (:meth:`arm`) and restart on Set_Watchdog
    (:meth:`restart`).  Every *accepted* setpoint feeds the watchdog; with ``require_auth``
    plain Set_Input_Vel frames are refused and only authenticated setpoints (whose MAC and
    freshness the drive has already checked, so a replayed or re-sent frame never gets here)
    feed it.

    With ``require_neutral``, setpoints after arming are refused until one is neutral
    (``|v| <= neutral_revps``): a host that starts with a non-zero command does not move the
    wheel (and, not feeding the watchdog, trips it).

    The last accepted authenticated frame's ``stop_ref_revps`` is kept for the coordinated
    stop.  The host monitor is fed by every Host_Heartbeat whose alive counter changed.
    """

    __slots__ = (
        "_host_counter",
        "host_last_ns",
        "host_timeout_ms",
        "host_timeout_ns",
        "last_feed_ns",
        "last_reject",
        "neutral_revps",
        "neutral_seen",
        "require_auth",
        "require_neutral",
        "stop_decel_revps2",
        "stop_ref_revps",
        "timeout_ns",
    )

    def __init__(
        self,
        timeout_ms: int,
        stop_decel_revps2: float,
        require_auth: bool,
        host_timeout_ms: int,
        require_neutral: bool = False,
        *,
        neutral_revps: float = 0.01,
    ) -> None:
        self.timeout_ns = 0
        self.stop_decel_revps2 = 0.0
        self.require_auth = False
        self.require_neutral = False
        self.host_timeout_ms = 0
        self.host_timeout_ns = 0
        self.neutral_revps = neutral_revps
        self.last_feed_ns = 0
        self.host_last_ns = 0
        self.stop_ref_revps = 0.0
        self.neutral_seen = False
        self.last_reject = ""
        self._host_counter: int | None = None
        self.configure(
            timeout_ms, stop_decel_revps2, require_auth, host_timeout_ms, require_neutral
        )

    def configure(
        self,
        timeout_ms: int,
        stop_decel_revps2: float,
        require_auth: bool,
        host_timeout_ms: int,
        require_neutral: bool = False,
    ) -> None:
        """Set the timeouts (ms, 0: off), the stop deceleration (rev/s^2) and the refusal rules."""
        self.timeout_ns = int(timeout_ms) * 1_000_000
        self.stop_decel_revps2 = float(stop_decel_revps2)
        self.require_auth = bool(require_auth)
        self.require_neutral = bool(require_neutral)
        self.host_timeout_ms = int(host_timeout_ms)
        self.host_timeout_ns = self.host_timeout_ms * 1_000_000

    def arm(self, now_ns: int) -> None:
        """The axis entered closed loop: start timing, wait for neutral."""
        self.restart(now_ns)
        self.stop_ref_revps = 0.0
        self.neutral_seen = False

    def restart(self, now_ns: int) -> None:
        """Restart both timers from ``now_ns`` (Set_Watchdog)."""
        self.last_feed_ns = now_ns
        self.host_last_ns = now_ns

    def _neutral_ok(self, vel_revps: float) -> bool:
        if self.neutral_seen or not self.require_neutral:
            return True
        if -self.neutral_revps <= vel_revps <= self.neutral_revps:
            self.neutral_seen = True
            return True
        self.last_reject = REJECT_NOT_NEUTRAL
        return False

    def accept_plain(self, now_ns: int, vel_revps: float = 0.0) -> bool:
        """A Set_Input_Vel arrived: apply it (and feed) unless authentication is required."""
        if self.require_auth:
            self.last_reject = REJECT_PLAIN
            return False
        if not self._neutral_ok(vel_revps):
            return False
        self.stop_ref_revps = 0.0
        self.last_feed_ns = now_ns
        return True

    def accept_auth(self, now_ns: int, vel_revps: float = 0.0, stop_ref_revps: float = 0.0) -> bool:
        """An authenticated, fresh Set_Input_Vel_Auth arrived: apply it (and feed)?"""
        if not self._neutral_ok(vel_revps):
            return False
        self.stop_ref_revps = stop_ref_revps
        self.last_feed_ns = now_ns
        return True

    def feed_host(self, alive_counter: int, now_ns: int) -> bool:
        """A Host_Heartbeat arrived: feed the host monitor if its alive counter changed."""
        if alive_counter == self._host_counter:
            self.last_reject = REJECT_HOST_REPEATED
            return False
        self._host_counter = alive_counter
        self.host_last_ns = now_ns
        return True

    def expired(self, now_ns: int) -> bool:
        """Whether no accepted setpoint fed the watchdog within its timeout, at ``now_ns``."""
        return self.timeout_ns > 0 and now_ns - self.last_feed_ns > self.timeout_ns

    def host_expired(self, now_ns: int) -> bool:
        """Whether no fresh Host_Heartbeat came within the host timeout, at ``now_ns``."""
        return self.host_timeout_ns > 0 and now_ns - self.host_last_ns > self.host_timeout_ns
