"""The parameter protocol: read and write with an own retry loop, trusted only when echoed (SPEC C1).

Parameters are addressed by the autopilot's names (``get_param``/``set_param``) or by the product's
neutral names through the profile (``get_params``/``set_params``, with unit conversions). A write is
trusted only when a PARAM_VALUE echo carries the same name and the float32-rounded value (integers:
the same integer through the vehicle's int encoding, ``companion.link.param_codec``); anything else
is a refusal or a timeout, never a silent success. Timeouts are vehicle time (``LinkTimeouts``).
"""
from __future__ import annotations

import collections
import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable

from companion.link import param_codec
from companion.link.clock import VehicleClock
from companion.link.errors import ParamRefused, ParamTimeout, ProfileError
from companion.link.transport import Transport
from companion.link.vehicle_state import VehicleAnnouncements

if TYPE_CHECKING:
    from companion.link.profile import AutopilotProfile

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ForeignChange:
    """A parameter changed by someone else: its value before, the value announced, when (vehicle s)."""

    name: str
    before: float
    value: float
    time_s: float


class ParameterChannel:
    """Parameter reads and writes, and the latest value of every parameter the vehicle sent."""

    def __init__(self, transport: Transport, clock: VehicleClock, announcements: VehicleAnnouncements) -> None:
        self.transport = transport
        self.clock = clock
        self.announcements = announcements
        self.profile: AutopilotProfile | None = None  # the autopilot profile, once known (neutral names)
        self.int_encoding: param_codec.IntEncoding = "cast"
        self.cache: dict[str, float] = {}
        self.types: dict[str, int] = {}
        self.events: dict[str, int] = collections.defaultdict(int)  # name -> PARAM_VALUEs received
        # parameters whose changes by anyone else are watched (a procedure's footprint), and the
        # changes seen: name -> ForeignChange (the vehicle announced a value no write of ours asked for)
        self.watched: set[str] = set()
        self.foreign: dict[str, ForeignChange] = {}
        # name -> every value our writes asked for since watch(): an echo of an earlier write of
        # ours can arrive after a later one was asked for (a slow link), and is still ours
        self._asked: dict[str, list[float]] = collections.defaultdict(list)
        self._write_listeners: list[Callable[[str, float], None]] = []
        transport.on("PARAM_VALUE", self._on_param_value)

    @property
    def try_s(self) -> float:
        return self.clock.timeouts.param_try_s

    def _on_param_value(self, msg: Any) -> None:
        if not self.transport.from_vehicle(msg):
            return
        name = param_codec.param_id_str(msg.param_id)
        value = param_codec.decode_value(msg.param_value, msg.param_type, self.int_encoding)
        self.types[name] = msg.param_type
        if name in self.watched and name in self.cache:
            self._note_foreign(name, self.cache[name], value, msg.param_type)
        self.cache[name] = value
        self.events[name] += 1

    def _note_foreign(self, name: str, before: float, value: float, param_type: int) -> None:
        """A watched parameter announced with a new value that no write of ours asked for: someone
        else (a ground station, a script) changed it."""
        if param_codec.echo_matches(before, value, param_type):
            return
        if self.ours(name, value):
            return
        change = ForeignChange(name, before, value, self.clock.vehicle_time_s)
        self.foreign[name] = change
        log.warning("%s changed from %g to %g by someone else", name, before, value)

    def watch(self, names) -> None:
        """Watch these parameters for changes by anyone else (from now on; earlier changes and
        the values our writes asked for forgotten)."""
        profile = self.profile
        resetting = set() if profile is None else {profile.params.get(n, n) for n in profile.self_resetting}
        self.watched = set(names) - resetting
        self.foreign = {}
        self._asked.clear()

    def on_write(self, listener: Callable[[str, float], None]) -> Callable[[], None]:
        """Call ``listener(name, value)`` before each write is sent (a crash trail records it);
        returns the unsubscribe call."""
        self._write_listeners.append(listener)
        return lambda: self._write_listeners.remove(listener) if listener in self._write_listeners else None

    def ours(self, name: str, value: float) -> bool:
        """``value`` of ``name`` is one a write of ours asked for since :meth:`watch`."""
        param_type = self.types.get(name, param_codec.REAL32)
        return any(param_codec.echo_matches(asked, value, param_type) for asked in self._asked.get(name, ()))

    # ------------------------------------------------------------------ by autopilot name
    def request(self, name: str) -> None:
        """PARAM_REQUEST_READ by name (the answer arrives through the PARAM_VALUE handler)."""
        self.transport.mav.param_request_read_send(self.transport.system_id, self.transport.autopilot_component,
                                                   name.encode("ascii"), -1)

    def get_param(self, name: str, *, retries: int = 3) -> float:
        """Read one parameter by its autopilot name (PARAM_REQUEST_READ, retried); ParamTimeout."""
        param_codec.validate_param_name(name)
        for _attempt in range(retries):
            since = self.events[name]
            self.request(name)
            if self.clock.wait_until(lambda: self.events[name] > since, self.try_s):
                return self.cache[name]
        raise ParamTimeout(f"no PARAM_VALUE for {name} after {retries} tries", name=name)

    def set_param(self, name: str, value: float, *, retries: int = 3) -> float:
        """Write one parameter by its autopilot name and return the echoed value.

        ParamRefused when the echo carries another value, when the vehicle sends a STATUSTEXT
        warning naming the parameter, or for a non-finite value (refused locally, never sent);
        ParamTimeout when nothing answers after ``retries`` tries of ``param_try_s`` vehicle
        seconds each."""
        param_codec.validate_param_name(name)
        if not math.isfinite(value):
            raise ParamRefused(f"{name}: non-finite value {value!r} refused locally (not sent)", name=name, value=value)
        if name not in self.types and self.int_encoding == "bytewise":
            self.get_param(name, retries=retries)  # the type decides the bytes we send
        param_type = self.types.get(name, param_codec.REAL32)
        wire_value = param_codec.encode_value(value, param_type, self.int_encoding)
        for listener in list(self._write_listeners):
            listener(name, value)
        asked = self._asked[name]
        asked.append(value)
        del asked[:-256]  # bounded for a resident loop that writes for hours without a watch
        return self._write(name, value, wire_value, param_type, retries)

    def _write(self, name: str, value: float, wire_value: float, param_type: int, retries: int) -> float:
        for _attempt in range(retries):
            since_param = self.events[name]
            since_text = self.announcements.statustext_count
            self.transport.mav.param_set_send(self.transport.system_id, self.transport.autopilot_component,
                                              name.encode("ascii"), wire_value, param_type)
            state: dict[str, Any] = {"mismatch": None, "refusal": None}

            def answered() -> bool:
                if self.events[name] > since_param:
                    echoed = self.cache[name]
                    if param_codec.echo_matches(value, echoed, self.types.get(name, param_type)):
                        return True
                    state["mismatch"] = echoed
                state["refusal"] = self.announcements.refusal_naming(name, since_text)
                return state["refusal"] is not None

            if self.clock.wait_until(answered, self.try_s) and state["refusal"] is None:
                return self.cache[name]
            if state["refusal"] is not None:
                raise ParamRefused(f"{name}={value!r} refused by the vehicle: {state['refusal']!r}", name=name,
                                   value=value, echoed=state["mismatch"])
            if state["mismatch"] is not None:
                raise ParamRefused(f"{name}={value!r} refused: the vehicle echoed {state['mismatch']!r}", name=name,
                                   value=value, echoed=state["mismatch"])
        raise ParamTimeout(f"no echo for {name}={value!r} after {retries} tries", name=name, value=value)

    def read_first(self, names: Iterable[str], default: float) -> float:
        """The first of ``names`` the vehicle answers for, else ``default`` (logged)."""
        names = list(names)
        for name in names:
            try:
                return self.get_param(name, retries=2)
            except ParamTimeout:
                continue
        log.warning("none of %s answered; assuming %g", names, default)
        return default

    # ------------------------------------------------------------------ by neutral name
    def _profile(self) -> AutopilotProfile:
        if self.profile is None:
            raise ProfileError("no profile yet (still connecting)")
        return self.profile

    def get_params(self, neutral_names: Iterable[str]) -> dict[str, float]:
        """Read parameters by neutral name (profile mapping and unit conversion applied)."""
        profile = self._profile()
        return {neutral: profile.to_neutral_value(neutral, self._read_neutral(neutral)) for neutral in neutral_names}

    def _read_neutral(self, neutral: str) -> float:
        candidates = self._profile().native_candidates(neutral)
        for native in candidates[:-1]:
            try:
                return self.get_param(native, retries=1)
            except ParamTimeout:
                continue
        return self.get_param(candidates[-1])

    def set_params(self, neutral_values: dict[str, float]) -> dict[str, float]:
        """Write parameters by neutral name; returns neutral name → confirmed value. Writes stop at
        the first failure (ParamRefused / ParamTimeout propagate)."""
        profile = self._profile()
        confirmed: dict[str, float] = {}
        for neutral, value in neutral_values.items():
            native = profile.native_param(neutral)
            echoed = self.set_param(native, profile.to_native_value(neutral, value))
            confirmed[neutral] = profile.to_neutral_value(neutral, echoed)
        return confirmed
