"""The paper's five channels over MQTT for one simulated vehicle (the second ``VehicleLink``).

On connect the link subscribes to its own ``<agv-id>/motion_channel`` and ``action_channel``
(QoS 1), publishes its description (retained, QoS 1) and its status; the MQTT last will is
status ``OFFLINE`` (retained, QoS 1), and ``goodbye`` publishes the same on a clean stop.
``movement_channel`` goes out every ``movement_interval`` seconds, ``status_channel`` whenever its
content changes (and at least every ``status_interval`` seconds).

Received items come bare or wrapped in the context broker's MQTT notification (the mqtt-ngsi
bridge's NGSI -> MQTT direction; :func:`fleet.paper.schemas.unwrap`). Each is checked
(:class:`~fleet.paper.messages.MotionItem` / ``ActionItem``, then the point against the map), then
offered to the :class:`~fleet.paper.tasks.TaskBook` (Fig. 5: a task's motions, then its actions; a
wait action ends it). A refused item is a log line and an entry in the status's ``errors``;
nothing else changes. Items run one at a time through the VDA 5050 executor of
:class:`~fleet.sim.vehicle.SimVehicle`: a motion is a two-node order from where the vehicle stands
to the point (edge ``maxSpeed`` and the vehicle's limits capped by the item's per-axis limits while
it runs), an action a one-node order with the matching action (load -> pick, unload -> drop,
idle/wait -> wait, charge -> startCharging). A charging vehicle is told ``stopCharging`` before
its next motion.
"""

from __future__ import annotations

import json
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from fleet.paper import channels, schemas
from fleet.paper.channels import Channel
from fleet.paper.errors import MessageError
from fleet.paper.messages import (
    ActionItem, ActionKind, Description, HeaderCounter, MachineState, MotionItem, Movement, Physical, Status,
    StatusError,
)
from fleet.paper.tasks import Step, TaskBook
from fleet.sim.kinematics import Limits, wrap
from fleet.sim.mqtt_pump import MqttPump
from fleet.sim.vehicle import Outbox, SimVehicle
from fleet.vda5050.messages import Action, ActionParameter, ActionStatus, Edge, InstantActions, Node, NodePosition, Order

log = logging.getLogger("fleet.sim.paper")

SKILLS = ("move", "load", "unload", "idle", "wait", "charge")
VDA_ACTION = {ActionKind.LOAD: "pick", ActionKind.UNLOAD: "drop", ActionKind.IDLE: "wait",
              ActionKind.WAIT: "wait", ActionKind.CHARGE: "startCharging"}
MAX_ERRORS = 10
NGSI_UNSAFE = str.maketrans({"'": "`", '"': "`", "(": "[", ")": "]", "<": "lt ", ">": "gt ", "=": ":", ";": ","})


@dataclass(frozen=True)
class PaperLinkConfig:
    host: str = "127.0.0.1"
    port: int = 1883
    movement_interval: float | None = 1.0  # None: no movement messages
    status_interval: float = 30.0
    keepalive: int = 15
    username: str | None = None
    password: str | None = None

    def __post_init__(self) -> None:
        if not self.status_interval > 0:
            raise ValueError(f"status_interval must be > 0 s, got {self.status_interval}")
        if self.movement_interval is not None and not self.movement_interval > 0:
            raise ValueError(f"movement_interval must be > 0 s, got {self.movement_interval}")


def safe_text(text: str, limit: int) -> str:
    """Text for the status: without the characters NGSI-v2 refuses in values (the status becomes an
    entity on the context broker through the bridge), at most ``limit`` characters."""
    return text.replace(" = ", " is ").translate(NGSI_UNSAFE)[:limit]


def _dumps(message: dict[str, Any]) -> bytes:
    return json.dumps(message, separators=(",", ":")).encode("utf-8")


class PaperLink:
    def __init__(self, vehicle: SimVehicle, config: PaperLinkConfig, pump: MqttPump) -> None:
        self.vehicle = vehicle
        self.config = config
        self.pump = pump
        self.agv_id = channels.check_agv_id(vehicle.spec.serial)
        self.headers = HeaderCounter(vehicle.spec.site.map_id)
        self.book = TaskBook()
        self._base_spec = vehicle.spec
        self._topic = {c: channels.topic(self.agv_id, c) for c in Channel}
        self._inbox: deque[tuple[Channel, bytes]] = deque(maxlen=1000)
        self._errors: deque[StatusError] = deque(maxlen=MAX_ERRORS)
        self.refused = 0
        self._orders = 0
        self._order_id = ""
        self._start_refused = False
        self._last_status: dict[str, Any] | None = None
        self._status_due = float("-inf")
        self._movement_due = float("-inf")
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"plantkg-sim-paper-{self.agv_id}",
                                  clean_session=True)
        if config.username is not None:
            self.client.username_pw_set(config.username, config.password)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        will = Status(self.headers.next(Channel.STATUS.value), self.agv_id, MachineState.OFFLINE).to_json()
        rule = channels.rule(Channel.STATUS)
        self.client.will_set(self._topic[Channel.STATUS], _dumps(will), qos=rule.qos, retain=rule.retain)

    # ------------------------------------------------------------- lifecycle
    def start(self) -> None:
        self.pump.add(self.client)
        self.client.connect_async(self.config.host, self.config.port, keepalive=self.config.keepalive)

    def connected(self) -> bool:
        return self.client.is_connected()

    def goodbye(self) -> Callable[[], bool]:
        if not self.client.is_connected():
            return lambda: False
        offline = Status(self.headers.next(Channel.STATUS.value), self.agv_id, MachineState.OFFLINE).to_json()
        return self._send(Channel.STATUS, offline).is_published

    def close(self) -> None:
        self.client.disconnect()
        self.pump.remove(self.client)

    def _on_connect(self, client: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        if reason.is_failure:
            log.warning("%s: broker refused the connection: %s", self.agv_id, reason)
            return
        for channel in (Channel.MOTION, Channel.ACTION):
            client.subscribe(self._topic[channel], qos=channels.rule(channel).qos)
        self._send(Channel.DESCRIPTION, self.description().to_json())
        self._last_status = None  # a fresh status right after (re)connecting

    def _on_message(self, _c: mqtt.Client, _u: Any, message: mqtt.MQTTMessage) -> None:
        channel = Channel.MOTION if message.topic == self._topic[Channel.MOTION] else Channel.ACTION
        self.receive(channel, bytes(message.payload))

    def receive(self, channel: Channel, payload: bytes) -> None:
        """Queue a payload received on ``channel`` until the next :meth:`poll` (a flood drops the oldest)."""
        self._inbox.append((channel, payload))

    # ------------------------------------------------------------- receiving
    def poll(self) -> None:
        while self._inbox:
            channel, payload = self._inbox.popleft()
            kind = schemas.Kind.MOTION_ITEM if channel is Channel.MOTION else schemas.Kind.ACTION_ITEM
            try:
                messages = schemas.unwrap(kind, schemas.load(kind, payload))
            except MessageError as exc:
                self._refuse(channel, "", exc.short)
                continue
            for raw in messages:
                self._receive(channel, kind, raw)
        self._execute()

    def _receive(self, channel: Channel, kind: schemas.Kind, raw: Any) -> None:
        id_key = "motion_id" if channel is Channel.MOTION else "action_id"
        item_id = raw.get(id_key) if isinstance(raw, dict) else None
        item_id = item_id if isinstance(item_id, str) else ""
        try:
            item = MotionItem.from_json(raw) if channel is Channel.MOTION else ActionItem.from_json(raw)
        except MessageError as exc:
            self._refuse(channel, item_id, exc.short)
            return
        if isinstance(item, MotionItem) and not self.vehicle.spec.site.contains(item.point[0], item.point[1]):
            site = self.vehicle.spec.site
            self._refuse(channel, item_id, f"point = {list(item.point)}: outside map {site.map_id}, "
                                           f"0..{site.width:g} x 0..{site.height:g} m")
            return
        verdict = self.book.offer(item)
        if verdict.duplicate:
            log.info("%s: %s %s received again: ignored", self.agv_id, kind.value, item_id)
        elif not verdict.accepted:
            self._refuse(channel, item_id, verdict.reason)
        else:
            log.info("%s: accepted %s %s (task %s, sequence %d)", self.agv_id, kind.value, item_id,
                     item.task_id, item.sequence)

    def _refuse(self, channel: Channel, item_id: str, reason: str) -> None:
        self.refused += 1
        log.warning("%s: refused on %s%s: %s", self.agv_id, channel.value, f" ({item_id})" if item_id else "", reason)
        self._errors.append(StatusError(channel.value, safe_text(item_id, 64), safe_text(reason, 300)))

    def _error(self, channel: Channel, item_id: str, reason: str) -> None:
        log.warning("%s: %s %s: %s", self.agv_id, channel.value, item_id, reason)
        self._errors.append(StatusError(channel.value, safe_text(item_id, 64), safe_text(reason, 300)))

    # ------------------------------------------------------------- executing
    def _execute(self) -> None:
        step = self.book.current
        if step is not None and self._step_done(step):
            self._finish(step)
        step = self.book.start_next()
        if step is not None:
            self._start(step)

    def _step_done(self, step: Step) -> bool:
        return self._start_refused or not self.vehicle.busy

    def _finish(self, step: Step) -> None:
        v = self.vehicle
        ok = not self._start_refused
        if ok and isinstance(step.item, ActionItem):
            state = v.actions.get(step.item_id)
            ok = state is not None and state.status is ActionStatus.FINISHED
            if not ok:
                reason = state.result_description if state is not None and state.result_description else "failed"
                self._error(Channel.ACTION, step.item_id, f"{step.item.action.value} failed: {reason}")
        v.spec = self._base_spec
        self.book.finish(ok)
        log.info("%s: %s %s of task %s %s", self.agv_id, "motion" if step.is_motion else "action", step.item_id,
                 step.task_id, "finished" if ok else "failed")
        if step.ends_task:
            log.info("%s: task %s ended", self.agv_id, step.task_id)

    def _start(self, step: Step) -> None:
        v = self.vehicle
        self._orders += 1
        self._order_id = f"paper-{self._orders}-{step.item_id}"
        pose, map_id = v.motion.pose, v.spec.site.map_id
        here = Node("here", 0, True, (), NodePosition(pose.x, pose.y, map_id))
        item = step.item
        if isinstance(item, MotionItem):
            if v.battery.charging:
                v.receive_instant_actions(InstantActions((Action("stopCharging", f"{self._order_id}-stop"),)))
            base = self._base_spec.limits
            v.spec = replace(self._base_spec, limits=Limits(
                min(base.v_max, item.max_velocity[0]), min(base.a_max, item.max_acceleration[0]),
                min(base.omega_max, item.max_velocity[2]), min(base.alpha_max, item.max_acceleration[2])))
            target = Node(item.point_id, 2, True, (), NodePosition(item.point[0], item.point[1], map_id, item.theta))
            edge = Edge(f"to-{item.point_id}", 1, "here", item.point_id, max_speed=item.max_velocity[0])
            order = Order(self._order_id, 0, (here, target), (edge,))
        else:
            params = (ActionParameter("duration", item.duration),) if item.duration is not None else ()
            action = Action(VDA_ACTION[item.action], item.action_id, parameters=params)
            order = Order(self._order_id, 0, (Node("here", 0, True, (action,), here.position),))
        self._start_refused = not v.receive_order(order)
        if self._start_refused:
            reason = v.errors[-1].description if v.errors else "refused by the vehicle"
            self._error(Channel.MOTION if step.is_motion else Channel.ACTION, step.item_id, f"not started: {reason}")

    # ------------------------------------------------------------- publishing
    def description(self) -> Description:
        s, lim = self._base_spec, self._base_spec.limits
        physical = Physical((lim.v_max, 0.0, lim.omega_max), (lim.a_max, 0.0, lim.alpha_max), s.max_load_mass,
                            s.length, s.width)
        return Description(self.headers.next(Channel.DESCRIPTION.value), self.agv_id, f"Simulated AGV {self.agv_id}",
                           s.manufacturer, SKILLS, physical)

    def _machine_state(self) -> MachineState:
        v, step = self.vehicle, self.book.current
        if v.battery.empty and not v.battery.charging:
            return MachineState.ERROR
        if step is not None:
            return MachineState.MOVING if step.is_motion else MachineState.ACTING
        return MachineState.CHARGING if v.battery.charging else MachineState.IDLE

    def status_fields(self) -> dict[str, Any]:
        """The status without its header (what "changed" compares)."""
        v, step = self.vehicle, self.book.current
        return {
            "agv_id": self.agv_id, "state": self._machine_state(),
            "battery": round(v.battery.charge, 1), "charging": v.battery.charging,
            "task_id": step.task_id if step else "",
            "motion_id": step.item_id if step and step.is_motion else "",
            "action_id": step.item_id if step and not step.is_motion else "",
            "last_finished_sequence": self.book.last_finished_sequence,
            "finished_task_id": self.book.finished_task_id,
            "refused": self.refused, "errors": tuple(self._errors),
        }

    def publish(self, outbox: Outbox, now: float) -> None:
        if not self.client.is_connected():
            return
        fields = self.status_fields()
        if fields != self._last_status or now >= self._status_due:
            status = Status(self.headers.next(Channel.STATUS.value), **fields)
            self._send(Channel.STATUS, status.to_json())
            self._last_status = fields
            self._status_due = now + self.config.status_interval
        interval = self.config.movement_interval
        if interval is not None and now >= self._movement_due:
            m = self.vehicle.motion
            movement = Movement(self.headers.next(Channel.MOVEMENT.value), self.agv_id, m.pose.x, m.pose.y,
                                wrap(m.pose.theta), m.v, m.omega)
            self._send(Channel.MOVEMENT, movement.to_json())
            following = self._movement_due + interval
            self._movement_due = following if following > now else now + interval

    def _send(self, channel: Channel, message: dict[str, Any]) -> mqtt.MQTTMessageInfo:
        rule = channels.rule(channel)
        return self.client.publish(self._topic[channel], _dumps(message), qos=rule.qos, retain=rule.retain)
