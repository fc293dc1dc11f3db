"""One simulated AGV executing VDA 5050 orders, stepped by a fixed tick (no clock of its own).

The adapter feeds it decoded messages (:meth:`SimVehicle.receive_order`,
:meth:`receive_instant_actions`) and calls :meth:`tick` with the tick length; the vehicle answers
with :meth:`state` and says through :meth:`take_outbox` what must be published now (a state on
every relevant event, a factsheet when asked). Tests drive it with any ``dt`` and no sleeps.

Order semantics (VDA 5050 2.1, section 6.6): released nodes (the base) are driven node by node,
edges between them; the horizon waits for an update. A new order is refused while another one is
still running (``orderError``) or when its first node is farther from the vehicle than its
``allowedDeviationXY``; an update (same ``orderId``, higher ``orderUpdateId``) must start at the
last base node (stitching), else ``orderUpdateError``; an older update is refused with
``orderUpdateError`` and the same one again is ignored. A refused order leaves the running one
untouched. Node actions run one after the other when the node is reached and driving waits for them
(NONE/SOFT blocking actions are run like HARD ones: a simplification); edge actions are RUNNING
while the edge is driven. ``actionStates`` go WAITING -> RUNNING -> FINISHED, or FAILED with an
entry in ``errors`` (unknown action type, bad parameter, charging away from a charger).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from fleet.sim import actions as catalogue
from fleet.sim.battery import Battery
from fleet.sim.kinematics import Limits, Motion, Pose, brake, drive_step, turn_step
from fleet.sim.map import SiteMap, Station
from fleet.vda5050.factsheet import Factsheet
from fleet.vda5050.messages import (
    Action, ActionState, ActionStatus, AgvPosition, BatteryState, Edge, EdgeState, ErrorLevel,
    InstantActions, Node, NodeState, Order, State, VehicleError,
)
from fleet.vda5050.order_rules import structure_problems

REJECTION_TYPES = ("validationError", "orderError", "orderUpdateError", "mapError")


@dataclass(frozen=True)
class VehicleSpec:
    manufacturer: str
    serial: str
    site: SiteMap
    start: Station
    limits: Limits = Limits()
    battery: Battery = Battery()
    times: catalogue.ActionTimes = catalogue.ActionTimes()
    default_deviation: float = 0.5  # m: allowedDeviationXY of a node that gives none
    series_name: str = "plantkg-sim"
    width: float = 0.6
    length: float = 0.9
    height: float = 0.4
    max_load_mass: float = 100.0


@dataclass(frozen=True)
class Outbox:
    state: bool = False
    factsheet: bool = False


@dataclass
class _Running:
    action: Action
    left: float


@dataclass
class SimVehicle:
    spec: VehicleSpec
    motion: Motion = field(init=False)
    battery: Battery = field(init=False)

    def __post_init__(self) -> None:
        s = self.spec.start
        self.motion = Motion(Pose(s.x, s.y, s.theta))
        self.battery = self.spec.battery
        self.order_id, self.order_update_id = "", 0
        self.last_node_id, self.last_node_sequence_id = "", 0
        self.nodes: list[Node] = []  # not yet reached, base then horizon
        self.edges: list[Edge] = []  # not yet left
        self.actions: dict[str, ActionState] = {}
        self.queue: deque[Action] = deque()  # node actions still to run here
        self.current: _Running | None = None
        self.cancelling: Action | None = None
        self.errors: list[VehicleError] = []
        self.driving = False
        self._dirty = True
        self._factsheet = False
        self._route_version = 0  # +1 whenever nodes/edges change
        self._route_cache: tuple[int, tuple[tuple[NodeState, ...], tuple[EdgeState, ...]]] | None = None

    # ---------------------------------------------------------------- inputs
    def receive_order(self, order: Order) -> bool:
        """Accept (True) or refuse (False, with a WARNING in ``errors``) an order or order update."""
        self._dirty = True
        problems = structure_problems(order)
        problems += [f"node {n.node_id}: the simulated vehicle needs a nodePosition"
                     for n in order.nodes if n.released and n.position is None]
        if problems:
            return self._refuse("validationError", order, "; ".join(problems))
        wrong_map = sorted({n.position.map_id for n in order.nodes if n.position and n.position.map_id != self.spec.site.map_id})
        if wrong_map:
            return self._refuse("mapError", order, f"map(s) {', '.join(wrong_map)} unknown; the vehicle is on {self.spec.site.map_id}")
        if order.order_id != self.order_id:
            return self._accept_new(order)
        if order.order_update_id < self.order_update_id:
            return self._refuse("orderUpdateError", order,
                                f"orderUpdateId {order.order_update_id} is older than {self.order_update_id}")
        if order.order_update_id == self.order_update_id:
            self._dirty = False
            return True  # a resent order: ignored, as the standard says
        return self._accept_update(order)

    def receive_instant_actions(self, message: InstantActions) -> None:
        self._dirty = True
        for action in message.actions:
            if action.action_type == "cancelOrder":
                self._cancel(action)
            elif action.action_type == "factsheetRequest":
                self._factsheet = True
                self._set(action, ActionStatus.FINISHED)
            elif action.action_type == "stateRequest":
                self._set(action, ActionStatus.FINISHED)
            elif action.action_type in catalogue.CHARGING:
                if self._charging_action(action):
                    self._set(action, ActionStatus.FINISHED)
            else:
                self._fail(action, f"actionType {action.action_type!r} is not supported as an instant action")

    def refuse_message(self, kind: str, reason: str) -> None:
        """A received message failed the schema: report it as ``validationError`` (section 6.6.4)."""
        self._add_error(VehicleError("validationError", ErrorLevel.WARNING, f"{kind}: {reason}"[:500]))
        self._dirty = True

    # ---------------------------------------------------------------- time
    def tick(self, dt: float) -> None:
        distance = 0.0
        if self.cancelling is not None:
            self._stop_motion(dt)
            if self.motion.stopped:
                self._set(self.cancelling, ActionStatus.FINISHED)
                self.cancelling = None
        else:
            self._run_actions(dt)
            if self.current is None and not self.queue:
                distance = self._drive(dt)
        charger = self.spec.site.charger_at(self.motion.pose.x, self.motion.pose.y)
        if self.battery.charging and charger is None:
            self.battery = self.battery.with_charging(False)
        was_empty = self.battery.empty
        self.battery = self.battery.step(dt, distance)
        if self.battery.empty and not was_empty:
            self._add_error(VehicleError("batteryEmpty", ErrorLevel.FATAL, "battery empty: the vehicle cannot drive; send it startCharging at a charger"))

    # ---------------------------------------------------------------- outputs
    def take_outbox(self) -> Outbox:
        out = Outbox(self._dirty, self._factsheet)
        self._dirty = self._factsheet = False
        return out

    def position(self) -> AgvPosition:
        p = self.motion.pose
        return AgvPosition(p.x, p.y, p.theta, self.spec.site.map_id)

    def _route_states(self) -> tuple[tuple[NodeState, ...], tuple[EdgeState, ...]]:
        """nodeStates/edgeStates, rebuilt only when the route changed (states go out at up to 10 Hz)."""
        if self._route_cache is None or self._route_cache[0] != self._route_version:
            self._route_cache = (self._route_version, (
                tuple(NodeState(n.node_id, n.sequence_id, n.released, n.position) for n in self.nodes),
                tuple(EdgeState(e.edge_id, e.sequence_id, e.released) for e in self.edges)))
        return self._route_cache[1]

    def state(self) -> State:
        route = self._route_states()
        return State(
            order_id=self.order_id, order_update_id=self.order_update_id,
            last_node_id=self.last_node_id, last_node_sequence_id=self.last_node_sequence_id,
            driving=self.driving,
            battery=BatteryState(self.battery.charge, self.battery.charging, self.battery.reach),
            node_states=route[0], edge_states=route[1],
            action_states=tuple(self.actions.values()),
            errors=tuple(self.errors),
            position=self.position(),
            velocity=(self.motion.v, self.motion.omega),
        )

    def factsheet(self) -> Factsheet:
        s, lim = self.spec, self.spec.limits
        return Factsheet(
            series_name=s.series_name, agv_kinematic="DIFF", agv_class="CARRIER", max_load_mass=s.max_load_mass,
            speed_min=0.0, speed_max=lim.v_max, acceleration_max=lim.a_max, deceleration_max=lim.a_max,
            height_max=s.height, width=s.width, length=s.length, agv_actions=catalogue.catalogue(),
            angular_speed_max=lim.omega_max, angular_acceleration_max=lim.alpha_max,
        )

    @property
    def busy(self) -> bool:
        return bool(self.nodes or self.queue or self.current or self.cancelling)

    # ---------------------------------------------------------------- orders
    def _refuse(self, error_type: str, order: Order, reason: str) -> bool:
        refs = (("orderId", order.order_id), ("orderUpdateId", str(order.order_update_id)))
        self._add_error(VehicleError(error_type, ErrorLevel.WARNING, reason, refs))
        return False

    def _accept_new(self, order: Order) -> bool:
        if self.busy:
            return self._refuse("orderError", order, f"still executing order {self.order_id!r}: "
                                "cancel it (cancelOrder) or send an update of it")
        first = order.nodes[0]
        assert first.position is not None  # released nodes have one (checked above)
        allowed = first.position.allowed_deviation_xy or self.spec.default_deviation
        gap = math.hypot(first.position.x - self.motion.pose.x, first.position.y - self.motion.pose.y)
        if gap > allowed:
            return self._refuse("orderError", order, f"first node {first.node_id} is {gap:.2f} m from the "
                                f"vehicle, more than its allowedDeviationXY {allowed} m")
        self._clear_rejections()
        self.actions.clear()
        self.order_id, self.order_update_id = order.order_id, order.order_update_id
        self.nodes, self.edges = list(order.nodes), list(order.edges)
        self._route_version += 1
        self._announce(order.nodes, order.edges)
        self._arrive()  # the vehicle stands on the first node
        return True

    def _decision_point(self) -> tuple[str, int]:
        released = [n for n in self.nodes if n.released]
        if released:
            return released[-1].node_id, released[-1].sequence_id
        return self.last_node_id, self.last_node_sequence_id

    def _accept_update(self, order: Order) -> bool:
        stitch = order.nodes[0]
        expected = self._decision_point()
        if (stitch.node_id, stitch.sequence_id) != expected:
            return self._refuse("orderUpdateError", order, f"the update starts at {stitch.node_id}/{stitch.sequence_id}, "
                                f"it must start at the last base node {expected[0]}/{expected[1]}")
        self._clear_rejections()
        self.nodes = [n for n in self.nodes if n.released]
        self.edges = [e for e in self.edges if e.released]
        new_actions = tuple(a for a in stitch.actions if a.action_id not in self.actions)
        if self.nodes:  # stitching node not reached yet: it gains the update's new actions
            last = self.nodes[-1]
            self.nodes[-1] = Node(last.node_id, last.sequence_id, True, last.actions + new_actions, last.position)
        else:  # standing on it: run them here
            self.queue.extend(new_actions)
        self.nodes += order.nodes[1:]
        self.edges += order.edges
        self._route_version += 1
        self.order_update_id = order.order_update_id
        self._announce((Node(stitch.node_id, stitch.sequence_id, True, new_actions), *order.nodes[1:]), order.edges)
        return True

    def _announce(self, nodes: tuple[Node, ...] | list[Node], edges: tuple[Edge, ...] | list[Edge]) -> None:
        for item in (*nodes, *edges):
            if item.released:
                for action in item.actions:
                    self.actions.setdefault(action.action_id, ActionState(action.action_id, ActionStatus.WAITING, action.action_type))

    def _cancel(self, action: Action) -> None:
        if not self.busy:
            self._fail(action, "no order to cancel", error_type="noOrderToCancel")
            return
        self._set(action, ActionStatus.RUNNING)
        for state in list(self.actions.values()):
            if not state.status.done and state.action_id != action.action_id:
                self.actions[state.action_id] = ActionState(state.action_id, ActionStatus.FAILED, state.action_type, "cancelled")
        self.nodes, self.edges = [], []
        self._route_version += 1
        self.queue.clear()
        self.current = None
        self.cancelling = action

    # ---------------------------------------------------------------- execution
    def _arrive(self) -> None:
        node = self.nodes.pop(0)
        self._route_version += 1
        if self.edges and self.edges[0].end_node_id == node.node_id and self.edges[0].sequence_id < node.sequence_id:
            for action in self.edges.pop(0).actions:
                if self.actions.get(action.action_id, None) and self.actions[action.action_id].status is ActionStatus.RUNNING:
                    self._set(action, ActionStatus.FINISHED)
        self.last_node_id, self.last_node_sequence_id = node.node_id, node.sequence_id
        self.queue.extend(node.actions)
        self._dirty = True

    def _run_actions(self, dt: float) -> None:
        if self.current is not None:
            self.current.left -= dt
            if self.current.left > 1e-9:
                return
            self._set(self.current.action, ActionStatus.FINISHED)
            self.current = None
        while self.current is None and self.queue:
            self._start(self.queue.popleft())

    def _start(self, action: Action) -> None:
        if action.action_type not in catalogue.NODE_ACTIONS:
            self._fail(action, f"actionType {action.action_type!r} is not supported here")
            return
        if action.action_type in catalogue.CHARGING:
            if self._charging_action(action):
                self._set(action, ActionStatus.FINISHED)
            return
        try:
            seconds = catalogue.duration(action, self.spec.times)
        except catalogue.ActionParameterError as exc:
            self._fail(action, str(exc))
            return
        self._set(action, ActionStatus.RUNNING)
        self.current = _Running(action, seconds)

    def _charging_action(self, action: Action) -> bool:
        if action.action_type == "stopCharging":
            self.battery = self.battery.with_charging(False)
            return True
        if self.spec.site.charger_at(self.motion.pose.x, self.motion.pose.y) is None:
            self._fail(action, f"not on a charger at ({self.motion.pose.x:.2f}, {self.motion.pose.y:.2f})")
            return False
        if self.driving or not self.motion.stopped:
            self._fail(action, "cannot start charging while moving")
            return False
        self.battery = self.battery.with_charging(True)
        return True

    def _drive(self, dt: float) -> float:
        target = self.nodes[0] if self.nodes and self.nodes[0].released else None
        if target is None or (self.battery.empty and not self.battery.charging) or self.battery.charging:
            self._stop_motion(dt)
            return 0.0
        if not self.driving:
            self.driving = True
            self._dirty = True
            if self.edges and self.edges[0].released:
                for action in self.edges[0].actions:
                    if action.action_type in catalogue.NODE_ACTIONS:
                        self._set(action, ActionStatus.RUNNING)
                    else:
                        self._fail(action, f"actionType {action.action_type!r} is not supported on an edge")
        pos = target.position
        assert pos is not None
        edge = self.edges[0] if self.edges else None
        before = self.motion.pose
        motion, travelled, arrived = drive_step(self.motion, pos.x, pos.y, self.spec.limits, dt,
                                                edge.max_speed if edge else None)
        if arrived and pos.theta is not None:
            motion, arrived = turn_step(motion, pos.theta, self.spec.limits, dt)
        self.motion = motion
        if arrived:
            self.driving = False
            self._arrive()
        return travelled if travelled else math.hypot(motion.pose.x - before.x, motion.pose.y - before.y)

    def _stop_motion(self, dt: float) -> None:
        if not self.motion.stopped:
            lim = self.spec.limits
            self.motion = Motion(self.motion.pose, brake(self.motion.v, lim.a_max, dt), brake(self.motion.omega, lim.alpha_max, dt))
            p = self.motion.pose
            self.motion = Motion(Pose(p.x + self.motion.v * dt * math.cos(p.theta), p.y + self.motion.v * dt * math.sin(p.theta),
                                      p.theta + self.motion.omega * dt), self.motion.v, self.motion.omega)
        if self.motion.stopped and self.driving:
            self.driving = False
            self._dirty = True

    # ---------------------------------------------------------------- bookkeeping
    def _set(self, action: Action, status: ActionStatus, result: str | None = None) -> None:
        self.actions[action.action_id] = ActionState(action.action_id, status, action.action_type, result)
        self._dirty = True

    def _fail(self, action: Action, reason: str, error_type: str = "actionError") -> None:
        self._set(action, ActionStatus.FAILED, reason[:200])
        refs = (("actionId", action.action_id), ("actionType", action.action_type))
        self._add_error(VehicleError(error_type, ErrorLevel.WARNING, reason, refs))

    def _add_error(self, error: VehicleError) -> None:
        self.errors.append(error)
        del self.errors[:-20]  # keep the newest 20: state stays small

    def _clear_rejections(self) -> None:
        self.errors = [e for e in self.errors if e.error_type not in REJECTION_TYPES]
