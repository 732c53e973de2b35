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

    def decide(self, j: int, st):
        """Stage j's hold (:meth:`console.hold.OperatorHold.decide`): a generator of what it asks
        of its coordinator that returns the stage's :class:`mission.events.Decided`."""
        o = yield from self.hold.decide(j, st)
        return ev.Decided(j, o.deploy, o.planning_ms, time.time(), o.passengers, o.recommended, o.forced, o.vetoed,
                          o.hold, o.gain)

    def close(self) -> None:
        """The server and the key's worker stop."""
        self.desk.close()
        self.server.close()


def open_console(setup, settings, node, served, out_dir, plan, clock, stop) -> Console:
    """The console of a coordinator's mission (its :class:`coordinator.setup.MissionSetup`, its
    session ``node`` open): the credential in ``out_dir/operator.token``, the page's server, the
    operator's Zenoh key. ``settings``: the :class:`console.hold.OperatorSettings`; ``served()``:
    the mission state as stored (what State answers from); ``plan(j, state, constraints)``: its
    planner's stage step (:func:`coordinator.planning.plan_step`); ``clock``, ``stop``: its clock and
    stop request."""
    from world.scene import build_scene

    view = ConsoleView(build_scene(setup.scenario), setup.problem, setup.mission, setup.planner_name, settings)
    desk = Desk(served, new_token(out_dir), view, setup.log)
    server = ConsoleServer(desk, view, settings)
    hold = OperatorHold(settings, desk, plan, setup.problem, setup.ids, setup.seed, clock, stop, setup.log)
    desk.listen(node, setup.mission)
    mode = ("watching only (--operator-timeout 0)" if settings.wait_s <= 0 else
            f"waits up to {settings.wait_s:g} s a stage" + (" (--operator-required)" if settings.required else ""))
    setup.log(f"coordinator: operator console at {server.url} ({mode}); operator key "
              f"marsupial/{setup.mission}/operator/<id>/action, credential in {out_dir}/operator.token")
    return Console(desk, view, hold, server)
