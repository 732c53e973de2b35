"""Opening and closing the console with a coordinator's mission (operator mode)."""
from __future__ import annotations

import time
from dataclasses import dataclass

from mission import events as ev

from console.desk import Desk, new_token
from console.hold import OperatorHold
from console.server import ConsoleServer
from console.view import ConsoleView


@dataclass
class Console:
    """The console's parts, as the coordinator holds them."""

    desk: Desk
    view: ConsoleView
    hold: OperatorHold
    server: ConsoleServer

    def decided(self, j: int, c):
        """Stage j's :class:`mission.events.Decided` after the operator's hold."""
        o = self.hold.decide(j, c)
        return ev.Decided(j, o.deploy, o.planning_ms, time.time(), o.passengers, o.recommended, o.forced, o.vetoed,
                          o.hold, o.gain)

    def close(self, c) -> None:
        """The server and the key's worker stop."""
        self.desk.close()
        self.server.close()


def open_console(c, out_dir, plan) -> Console:
    """The console of coordinator ``c`` (:class:`coordinator.node.Coordinator`, its session open):
    the credential in ``out_dir/operator.token``, the page's server, the operator's Zenoh key;
    ``plan(j, constraints)`` is its planner's stage step (:func:`coordinator.node.plan_step`)."""
    from world.scene import build_scene

    settings = c.config.operator
    view = ConsoleView(build_scene(c.setup.scenario), c.setup.problem, c.setup.mission, c.setup.planner_name, settings)
    desk = Desk(lambda: c.state, new_token(out_dir), view, c.log)
    server = ConsoleServer(desk, view, settings)
    hold = OperatorHold(settings, desk, plan, c.setup.seed, c.clock, c._stop, c.log)
    desk.listen(c.node, c.setup.mission)
    mode = ("watching only (--operator-timeout 0)" if settings.wait_s <= 0 else
            f"waits up to {settings.wait_s:g} s a stage" + (" (--operator-required)" if settings.required else ""))
    c.log(f"coordinator: operator console at {server.url} ({mode}); operator key "
          f"marsupial/{c.setup.mission}/operator/<id>/action, credential in {out_dir}/operator.token")
    return Console(desk, view, hold, server)
