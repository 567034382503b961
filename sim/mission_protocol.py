"""PX4 v1.16's mission protocol as a pure machine: a message and the time in, the
messages to send out (`MissionProtocol.handle`, `.tick`), as h11's state machine does for
HTTP. The simulated autopilot (sim/mavlink_endpoint.py) is its shell: it feeds what it
receives and sends what comes back; an accepted inclusion polygon reaches its vehicle
through `on_fence`."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mav

log = logging.getLogger(__name__)

# ----- the mission protocol, as PX4 v1.16's MavlinkMissionManager ----------------------
# (src/modules/mavlink/mavlink_mission.cpp): plans (mission, geofence, rally points) are
# uploaded with MISSION_COUNT, the vehicle requesting each item in turn and re-requesting
# the awaited one every 0.25 s, ending with its MISSION_ACK; downloaded with
# MISSION_REQUEST_LIST, the client requesting each item and ending with its ACK; cleared
# with MISSION_CLEAR_ALL. One transfer at a time; 5 s without a word from the partner
# abandons it ("Operation timeout").

MISSION, FENCE, RALLY = mav.MAV_MISSION_TYPE_MISSION, mav.MAV_MISSION_TYPE_FENCE, mav.MAV_MISSION_TYPE_RALLY
# PX4's limits: DM_KEY_FENCE_POINTS_MAX, DM_KEY_SAFE_POINTS_MAX; the mission's is per board.
MISSION_MAX_COUNT = {MISSION: 500, FENCE: 64, RALLY: 32}
MISSION_RETRY_S = 0.25  # MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT
MISSION_TIMEOUT_S = 5.0  # MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT
IDLE, SENDLIST, GETLIST = "idle", "sendlist", "getlist"

_MISSION_ACCEPTED, _MISSION_ERROR = mav.MAV_MISSION_ACCEPTED, mav.MAV_MISSION_ERROR
_FRAME_MISSION = mav.MAV_FRAME_MISSION
_FRAMES_FLOAT = {mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT}
_FRAMES_INT = {mav.MAV_FRAME_GLOBAL_INT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_FRAMES_RELATIVE = {mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_VERTEX = {mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION}
_CIRCLE = {mav.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, mav.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION}
_ROI = {mav.MAV_CMD_NAV_ROI, mav.MAV_CMD_DO_SET_ROI}
# Positional commands PX4 takes in a global frame, with the params (1-4) it keeps and
# sends back; a 4 here is a yaw (deg), which comes back in [0, 360).
_GLOBAL_COMMANDS: dict[int, tuple[int, ...]] = {
    mav.MAV_CMD_NAV_WAYPOINT: (1, 2, 4), mav.MAV_CMD_NAV_LOITER_UNLIM: (3, 4), mav.MAV_CMD_NAV_LOITER_TIME: (1, 2, 3),
    mav.MAV_CMD_NAV_LAND: (2, 4), mav.MAV_CMD_NAV_TAKEOFF: (4,), mav.MAV_CMD_NAV_LOITER_TO_ALT: (1, 2),
    mav.MAV_CMD_NAV_ROI: (), mav.MAV_CMD_DO_SET_ROI: (), mav.MAV_CMD_DO_SET_ROI_LOCATION: (),
    mav.MAV_CMD_NAV_VTOL_TAKEOFF: (4,), mav.MAV_CMD_NAV_VTOL_LAND: (4,), mav.MAV_CMD_CONDITION_GATE: (),
    mav.MAV_CMD_NAV_FENCE_RETURN_POINT: (), **dict.fromkeys(_VERTEX | _CIRCLE, (1,)),
    mav.MAV_CMD_NAV_RALLY_POINT: (), mav.MAV_CMD_COMPONENT_ARM_DISARM: (), mav.MAV_CMD_DO_AUTOTUNE_ENABLE: (),
}
_YAW_KEPT = {mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_LOITER_UNLIM, mav.MAV_CMD_NAV_LAND, mav.MAV_CMD_NAV_TAKEOFF,
             mav.MAV_CMD_NAV_VTOL_TAKEOFF, mav.MAV_CMD_NAV_VTOL_LAND}
# Commands without a position (MAV_FRAME_MISSION); all seven params are kept.
_MISSION_FRAME_COMMANDS = {
    getattr(mav, f"MAV_CMD_{name}") for name in (
        "DO_JUMP NAV_ROI DO_SET_ROI DO_WINCH DO_GRIPPER DO_CHANGE_SPEED DO_SET_HOME DO_LAND_START DO_TRIGGER_CONTROL "
        "DO_DIGICAM_CONTROL DO_MOUNT_CONFIGURE DO_MOUNT_CONTROL DO_GIMBAL_MANAGER_PITCHYAW SET_CAMERA_FOCUS "
        "DO_GIMBAL_MANAGER_CONFIGURE IMAGE_START_CAPTURE IMAGE_STOP_CAPTURE VIDEO_START_CAPTURE VIDEO_STOP_CAPTURE "
        "DO_CONTROL_VIDEO DO_SET_CAM_TRIGG_DIST OBLIQUE_SURVEY DO_SET_CAM_TRIGG_INTERVAL SET_CAMERA_MODE "
        "SET_CAMERA_SOURCE DO_VTOL_TRANSITION NAV_DELAY NAV_RETURN_TO_LAUNCH DO_SET_ROI_WPNEXT_OFFSET DO_SET_ROI_NONE "
        "CONDITION_DELAY CONDITION_DISTANCE DO_SET_ACTUATOR DO_AUTOTUNE_ENABLE COMPONENT_ARM_DISARM"
    ).split()
}
_NOT_IN_A_MISSION = _VERTEX | _CIRCLE | {mav.MAV_CMD_NAV_RALLY_POINT}


@dataclass(frozen=True)
class MissionItem:
    """One stored plan item as PX4 keeps it: in a global frame x/y are lat/lon in
    degrees and z the altitude; in MAV_FRAME_MISSION x/y/z are params 5-7."""

    command: int
    frame: int
    params: tuple[float, float, float, float]
    x: float
    y: float
    z: float
    autocontinue: int = 0


def parse_mission_item(msg: mav.MAVLink_message, int_mode: bool) -> MissionItem | int:
    """The item a MISSION_ITEM(_INT) carries, or the MAV_MISSION_RESULT refusing it
    (PX4's parse_mavlink_mission_item)."""
    frame, command = msg.frame, msg.command
    p = (msg.param1, msg.param2, msg.param3, msg.param4)
    if frame in _FRAMES_FLOAT or (int_mode and frame in _FRAMES_INT):
        keep = _GLOBAL_COMMANDS.get(command)
        if keep is None:
            return mav.MAV_MISSION_UNSUPPORTED
        if command in _ROI and int(p[0]) not in (mav.MAV_ROI_LOCATION, mav.MAV_ROI_NONE):
            return mav.MAV_MISSION_INVALID_PARAM1
        kept = [p[i] if i + 1 in keep else 0.0 for i in range(4)]
        if command in _VERTEX:
            kept[0] = float(int(p[0] + 0.5))  # the vertex count
        if command in _YAW_KEPT:
            kept[3] = p[3] % 360.0
        lat, lon = (msg.x * 1e-7, msg.y * 1e-7) if int_mode else (msg.x, msg.y)
        return MissionItem(command, frame, (kept[0], kept[1], kept[2], kept[3]), lat, lon, msg.z, msg.autocontinue)
    if frame == _FRAME_MISSION:
        if command not in _MISSION_FRAME_COMMANDS:
            return mav.MAV_MISSION_UNSUPPORTED
        if command in _ROI and int(p[0]) not in (mav.MAV_ROI_NONE, mav.MAV_ROI_WPNEXT, mav.MAV_ROI_WPINDEX):
            return mav.MAV_MISSION_INVALID_PARAM1
        return MissionItem(command, frame, p, msg.x, msg.y, msg.z, msg.autocontinue)
    return mav.MAV_MISSION_UNSUPPORTED_FRAME


def fence_polygons(items: list[MissionItem]) -> list[tuple[int, list[tuple[float, float]]]]:
    """The (command, [(lat, lon), …]) polygons of a geofence plan: each vertex item's
    param1 is the vertex count of its polygon."""
    polygons, i = [], 0
    while i < len(items):
        item = items[i]
        count = int(item.params[0]) if item.command in _VERTEX else 0
        if count > 0:
            polygons.append((item.command, [(v.x, v.y) for v in items[i:i + count]]))
            i += count
        else:
            i += 1
    return polygons


class MissionProtocol:
    """The mission protocol of one simulated autopilot (see the section comment). Like
    PX4 it starts in float mode (MISSION_REQUEST / MISSION_ITEM) and switches to the
    int messages when the client uses them or refuses the float ones with
    MAV_MISSION_UNSUPPORTED, as MAVSDK does."""

    def __init__(self, sysid: int, encoder: mav.MAVLink,
                 on_fence: Callable[[list[tuple[float, float]]], None] = lambda polygon: None,
                 home: Callable[[], MissionItem] | None = None) -> None:
        self.sysid = sysid
        self._home = home  # ArduPilot: a mission's item 0 is home, whatever was uploaded there
        self._mav = encoder  # builds messages (a MAVLink_message); sending is the caller's
        self._on_fence = on_fence
        self._now = 0.0
        self._out: list[mav.MAVLink_message] = []
        self.plans: dict[int, list[MissionItem]] = {MISSION: [], FENCE: [], RALLY: []}
        self.current_seq = 0  # the mission's current item (items sent with current=1)
        self.state = IDLE
        self.mission_type = MISSION  # of the transfer under way, or the last one
        self.int_mode = False
        self.partner = (0, 0)
        self.transfer_count = 0
        self.transfer_seq = 0
        self._transfer_items: list[MissionItem] = []
        self._transfer_current = -1
        self._in_progress = False  # PX4's _transfer_in_progress: an upload holds the store
        self._last_sent = 0.0
        self._last_recv = 0.0

    # ----- the machine's two inputs ---------------------------------------------------

    def handles(self, name: str) -> bool:
        """Whether a message of this type (MAVLink name) belongs to the protocol."""
        return callable(getattr(self, f"on_{name.lower()}", None))

    def handle(self, msg: mav.MAVLink_message, now: float) -> list[mav.MAVLink_message]:
        """One message from a client at `now` (monotonic s); the messages to send back."""
        self._now, self._out = now, []
        getattr(self, f"on_{msg.get_type().lower()}")(msg)
        return self._out

    def tick(self, now: float) -> list[mav.MAVLink_message]:
        """Time passing: re-request the awaited item, or give the transfer up (PX4's
        send()); the messages to send."""
        self._now, self._out = now, []
        if self.state == GETLIST and self._last_sent > 0 and now - self._last_sent > MISSION_RETRY_S:
            self._request(self.transfer_seq)
        elif self.state != IDLE and self._last_recv > 0 and now - self._last_recv > MISSION_TIMEOUT_S:
            self._critical("Operation timeout")
            log.info("sysid %d: mission transfer (type %d) timed out", self.sysid, self.mission_type)
            self.state = IDLE
            self._in_progress = False
        elif self.state == IDLE:
            self._last_sent = self._last_recv = 0.0
        return self._out

    # ----- helpers -------------------------------------------------------------------

    def _count(self, mission_type: int) -> int:
        return len(self.plans.get(mission_type, ()))

    def _for_me(self, msg: mav.MAVLink_message) -> bool:
        return msg.target_system == self.sysid and msg.target_component in (
            mav.MAV_COMP_ID_AUTOPILOT1, mav.MAV_COMP_ID_MISSIONPLANNER, mav.MAV_COMP_ID_ALL,
        )

    def _send(self, msg: mav.MAVLink_message) -> None:
        self._out.append(msg)

    def _critical(self, text: str) -> None:
        self._send(self._mav.statustext_encode(mav.MAV_SEVERITY_CRITICAL, text.encode()))

    def _ack(self, to: tuple[int, int], result: int) -> None:
        self._send(self._mav.mission_ack_encode(to[0], to[1], result, self.mission_type))

    def _request(self, seq: int) -> None:
        if seq >= MISSION_MAX_COUNT.get(self.mission_type, 0):
            self._critical("ERROR: Waypoint index exceeds list capacity")
            return
        self._last_sent = self._now
        encode = self._mav.mission_request_int_encode if self.int_mode else self._mav.mission_request_encode
        self._send(encode(self.partner[0], self.partner[1], seq, self.mission_type))

    def _send_item(self, seq: int) -> None:
        item = self.plans[self.mission_type][seq]
        frame, params, x, y = item.frame, item.params, item.x, item.y
        if frame != _FRAME_MISSION:  # PX4 keeps a fence vertex's altitude as absolute
            relative = frame in _FRAMES_RELATIVE and self.mission_type != FENCE
            if self.int_mode:
                frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT if relative else mav.MAV_FRAME_GLOBAL_INT
                x, y = round(x * 1e7), round(y * 1e7)
            else:
                frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT if relative else mav.MAV_FRAME_GLOBAL
        elif self.int_mode:
            x, y = round(x), round(y)
        autocontinue = 0 if self.mission_type == FENCE else item.autocontinue
        encode = self._mav.mission_item_int_encode if self.int_mode else self._mav.mission_item_encode
        self._last_sent = self._now
        self._send(encode(
            self.partner[0], self.partner[1], seq, frame, item.command, int(seq == self.current_seq), autocontinue,
            *params, x, y, item.z, self.mission_type,
        ))

    def _store(self, mission_type: int, items: list[MissionItem], current: int = 0) -> None:
        if mission_type not in self.plans:
            return
        if mission_type == MISSION and items and self._home is not None:
            items = [self._home(), *items[1:]]
        self.plans[mission_type] = items
        if mission_type == MISSION:
            self.current_seq = current
        elif mission_type == FENCE:
            self._apply_fence()

    def _apply_fence(self) -> None:
        items = self.plans[FENCE]
        inclusions = [vertices for command, vertices in fence_polygons(items)
                      if command == mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION]
        self._on_fence(inclusions[0] if inclusions else [])
        if not items:
            log.info("sysid %d: fence cleared", self.sysid)
            return
        vertices = sum(1 for item in items if item.command in _VERTEX)
        circles = sum(1 for item in items if item.command in _CIRCLE)
        log.info("sysid %d: fence uploaded: %d vertices%s", self.sysid, vertices,
                 f", {circles} circles" if circles else "")

    # ----- messages ------------------------------------------------------------------

    def on_mission_count(self, msg: mav.MAVLink_mission_count_message) -> None:
        if not self._for_me(msg):
            return
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.state == IDLE:
            self._last_recv = self._now
            if self._in_progress:
                self._ack(sender, _MISSION_ERROR)
                return
            self._in_progress = True
            self.partner, self.mission_type = sender, msg.mission_type
            if msg.count > MISSION_MAX_COUNT.get(self.mission_type, 0):
                self._ack(self.partner, mav.MAV_MISSION_NO_SPACE)
                self._in_progress = False
                return
            if msg.count == 0:  # an empty plan clears the store
                self._store(self.mission_type, [])
                self._ack(self.partner, _MISSION_ACCEPTED)
                self._in_progress = False
                return
            if self.mission_type not in self.plans:
                self._in_progress = False
                self._ack(self.partner, mav.MAV_MISSION_INVALID)
                return
            self.state, self.transfer_seq, self.transfer_count = GETLIST, 0, msg.count
            self._transfer_items, self._transfer_current = [], -1
        elif self.state == GETLIST:
            self._last_recv = self._now
            if sender != self.partner:
                self._ack(sender, _MISSION_ERROR)
                return
            if self.transfer_seq != 0:  # at seq 0 our first request was lost: ask again
                self._critical("WPM: REJ. CMD: Busy")
                self._ack(self.partner, _MISSION_ERROR)
                return
        else:
            self._critical("WPM: IGN MISSION_COUNT: Busy")
            self._ack(sender, _MISSION_ERROR)
            return
        self._request(self.transfer_seq)

    def on_mission_item(self, msg: mav.MAVLink_mission_item_message) -> None:
        self.int_mode = False
        self._on_item(msg)

    def on_mission_item_int(self, msg: mav.MAVLink_mission_item_int_message) -> None:
        self.int_mode = True
        self._on_item(msg)

    def _on_item(self, msg: mav.MAVLink_message) -> None:
        if not self._for_me(msg):
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.partner:
            self._critical("REJ. MIS ITEM: partner id mismatch")
            return
        if msg.mission_type != self.mission_type:
            self._ack(self.partner, _MISSION_ERROR)
            return
        if self.state == IDLE:  # a repeat of the last item: our ACK was lost
            if self.transfer_seq == msg.seq + 1:
                self._ack(self.partner, _MISSION_ACCEPTED)
            else:
                self._critical("IGN MISSION_ITEM: No transfer")
                self._ack(self.partner, _MISSION_ERROR)
            return
        if self.state != GETLIST:
            self._critical("IGN MISSION_ITEM: Busy")
            self._ack(self.partner, _MISSION_ERROR)
            return
        self._last_recv = self._now
        if msg.seq != self.transfer_seq:
            return  # not the one asked for: the retry asks again
        item = parse_mission_item(msg, self.int_mode)
        if isinstance(item, int):
            self._critical("IGN MISSION_ITEM: Invalid item")
            self._abort(item)
            return
        if self.mission_type == MISSION and item.command in _NOT_IN_A_MISSION:
            self._abort(_MISSION_ERROR)
            return
        if self.mission_type == FENCE and item.command in _VERTEX and item.params[0] < 3:
            log.info("sysid %d: fence refused: a polygon of %d vertices", self.sysid, int(item.params[0]))
            self._abort(_MISSION_ERROR)  # PX4: "Fence: too few vertices"
            return
        if msg.current:
            self._transfer_current = msg.seq
        self._transfer_items.append(item)
        self.transfer_seq = msg.seq + 1
        if self.transfer_seq < self.transfer_count:
            self._request(self.transfer_seq)
            return
        self._store(self.mission_type, self._transfer_items, self._transfer_current)
        self.state = IDLE
        self._ack(self.partner, _MISSION_ACCEPTED)
        self._in_progress = False

    def _abort(self, result: int) -> None:
        self._ack(self.partner, result)
        self.state = IDLE
        self._in_progress = False

    def on_mission_request_list(self, msg: mav.MAVLink_mission_request_list_message) -> None:
        if not self._for_me(msg):
            return
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.transfer_seq == self._count(self.mission_type):
            # PX4: all items went out but the ACK never came (a quick reconnect). Its
            # check also ends an upload at that seq, leaving the store held (as PX4 does).
            self.state = IDLE
        if self.state == IDLE or (
            self.state == SENDLIST and msg.mission_type == self.mission_type and sender == self.partner
        ):
            self._last_recv = self._last_sent = self._now
            self.state, self.mission_type, self.partner = SENDLIST, msg.mission_type, sender
            self.transfer_seq, self.transfer_count = 0, self._count(msg.mission_type)
            self._send(self._mav.mission_count_encode(sender[0], sender[1], self.transfer_count, self.mission_type))
        else:
            self._send(self._mav.statustext_encode(
                mav.MAV_SEVERITY_INFO, b"Mission download request ignored, already active",
            ))

    def on_mission_request(self, msg: mav.MAVLink_mission_request_message) -> None:
        self.int_mode = False
        self._on_request(msg)

    def on_mission_request_int(self, msg: mav.MAVLink_mission_request_int_message) -> None:
        self.int_mode = True
        self._on_request(msg)

    def _on_request(self, msg: mav.MAVLink_message) -> None:
        if not self._for_me(msg):
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.partner:
            self._critical("WPM: REJ. CMD: partner id mismatch")
            return
        if self.state == IDLE:
            return  # PX4 ignores these silently (some OSDs send them)
        if self.state != SENDLIST:
            self._critical("WPM: REJ. CMD: Busy")
            return
        if msg.mission_type != self.mission_type:
            return
        self._last_recv = self._now
        if msg.seq == self.transfer_seq and self.transfer_seq < self.transfer_count:
            self.transfer_seq += 1
        elif msg.seq != self.transfer_seq - 1:  # not the last one again either
            self.state = IDLE
            self._ack(self.partner, _MISSION_ERROR)
            self._critical("WPM: REJ. CMD: Req. WP was unexpected")
            return
        if msg.seq < self._count(self.mission_type):
            self._send_item(msg.seq)
        else:
            self.state = IDLE
            self._ack(self.partner, _MISSION_ERROR)
            self._critical("WPM: REJ. CMD: Req. WP was unexpected")

    def on_mission_ack(self, msg: mav.MAVLink_mission_ack_message) -> None:
        if not self._for_me(msg):
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.partner:
            self._critical("REJ. WP CMD: partner id mismatch")
            return
        if self.state == SENDLIST and msg.mission_type == self.mission_type:
            self._last_recv = self._now
            self.state = IDLE  # the download is over, whatever the result
        elif self.state == GETLIST:
            if msg.type == mav.MAV_MISSION_UNSUPPORTED:  # the client wants the other encoding
                self.int_mode = not self.int_mode
                self._request(self.transfer_seq)
            elif msg.type == mav.MAV_MISSION_OPERATION_CANCELLED:
                self.state = IDLE
                self._in_progress = False

    def on_mission_clear_all(self, msg: mav.MAVLink_mission_clear_all_message) -> None:
        if not self._for_me(msg):
            return
        if self.state != IDLE:
            self._critical("WPM: IGN CLEAR CMD: Busy")
            return
        self._last_recv = self._now
        self.mission_type = msg.mission_type
        for mission_type in (MISSION, FENCE, RALLY) if msg.mission_type == mav.MAV_MISSION_TYPE_ALL else (msg.mission_type,):
            self._store(mission_type, [])
        self._ack((msg.get_srcSystem(), msg.get_srcComponent()), _MISSION_ACCEPTED)
