"""How a coordinator opens its mission, one function per step, each given what it needs and
returning what it opened: the session and the claim on the mission, then mission.db (with this
process's epoch) and the recorder (:func:`open_mission`); the mission state recovered from
mission.db (:func:`recovered`); what the session serves once the state is known and the
operator's console (:func:`serve`: the subscriptions, State, the token, the console); the
planner's warm-up thread (:func:`warming`, a generator of the waits its coordinator takes its
inbox in). The coordinator (:meth:`coordinator.node.Coordinator.run`) calls them in that order."""
from __future__ import annotations

import functools
import threading
from pathlib import Path
from typing import Generator, NamedTuple

from coordinator.clock import POLL_S
from coordinator.crew import Crew
from coordinator.planning import plan_step, warm_up
from coordinator.recorder import start as start_recording
from coordinator.setup import MissionSetup
from mission import state as ms
from mission import timers as tm
from mission.timeouts import DEFAULTS
from storage.missiondb import MissionStore
from wire import keys
from wire.link_filter import link_filter
from wire.transport import Node


class Opened(NamedTuple):
    """A mission opened by :func:`open_mission`: its session (None: stopped before it opened),
    mission.db, and the coordinator's clock when the mission's wall time began (s)."""

    node: Node | None
    store: MissionStore
    started: float


def open_mission(setup: MissionSetup, config, crew: Crew, stop: threading.Event, clock) -> Opened | None:
    """The session first (a duplicate is refused, or waited for, before mission.db is touched:
    ``crew.epochs``), then mission.db and the recorder (``crew.recording``); None when a standby
    stopped while the primary lived (nothing of its own to record). ``config``: the
    coordinator's (:class:`coordinator.node.CoordinatorConfig`)."""
    epochs, out = crew.epochs, Path(config.out_dir)
    links = link_filter(setup.scenario, setup.mission, "coordinator", realtime=config.realtime)
    node, claimed = epochs.session(functools.partial(Node, setup.zconf, stop=stop, links=links), config.standby)
    if not claimed:
        setup.log(f"coordinator: standby for mission {setup.mission} stopped; it never took over")
        return None
    started = clock()  # the mission's wall time: a standby's wait is not part of it
    out.mkdir(parents=True, exist_ok=True)
    meta = {"mission": setup.mission, "scenario": setup.scenario.name, "fingerprint": setup.fingerprint,
            "seed": setup.seed, "planner": setup.planner_name, "planner_options": setup.planner_options}
    # Higher than every epoch used before for this mission: the ones in mission.db and the
    # one a primary reported while this process stood by; 1 for a fresh mission.
    try:
        store = epochs.open_store(out / "mission.db", meta)
    except BaseException:
        if node is not None:
            node.close(DEFAULTS.close_s)
        raise
    start_recording(crew.recording, config, node, out, setup.scenario, setup.problem,
                    {k: meta[k] for k in ("mission", "scenario", "seed", "planner", "fingerprint")},
                    store.mission_events)
    return Opened(node, store, started)


def recovered(setup: MissionSetup, store: MissionStore, crew: Crew) -> ms.MissionState:
    """The mission state: recovery is the live fold over the stored events (the last one is this
    process's open); the first stage this process decides is told to ``crew.epochs``, and State
    answers from the state (``crew.answers``)."""
    state = ms.fold(setup.spec, store.mission_events())
    crew.epochs.first_stage = state.next_stage
    if state.resumed:
        setup.log(f"coordinator: resumed from {store.path}: {len(state.decisions)} stage(s) "
                  f"decided, continuing at stage {state.next_stage}")
    crew.answers.serve(state)
    return state


def serve(node: Node, setup: MissionSetup, config, crew: Crew, store: MissionStore, clock, stop: threading.Event):
    """Subscribed (``crew.inbound``), the carriers' tokens watched, State answered
    (``crew.answers``), its token declared, the line that says so; then operator mode's console
    (:func:`console.run.open_console`, its stage steps :func:`coordinator.planning.plan_step`),
    returned (None without operator mode: nothing of console/ loads then)."""
    answers = crew.answers
    crew.inbound.subscribe(node)
    node.serve(keys.state_key(setup.mission), answers.state_reply)
    node.token(keys.coordinator_alive(setup.mission))
    setup.log(f"coordinator: mission {setup.mission}, {len(setup.ids)} carriers, {setup.n_stages} stages, "
              f"planner {setup.planner_name} {setup.planner_options}, seed {setup.seed}, epoch "
              f"{crew.epochs.epoch}, {config.clock} clock")
    if config.operator is None:
        return None
    from console.run import open_console

    return open_console(setup, config.operator, node, lambda: answers.served, Path(config.out_dir),
                        functools.partial(plan_step, setup, store), clock, stop)


def warming(setup: MissionSetup, clock, stop: threading.Event) -> Generator[tm.Wait, object, None]:
    """The planner warming up (:func:`coordinator.planning.warm_up`) in a thread of its own: a
    generator of the waits its coordinator takes its inbox in (:class:`mission.timers.Wait`, a
    poll each), until the warm-up is over or a stop is requested. Warmed up once State answers
    and the token is out (:func:`serve`), while the inbox is taken: carriers that start meanwhile
    find a coordinator and their Hellos are answered (compiling the planner's kernels on a
    machine's first run takes seconds, more on a busy host)."""
    thread = threading.Thread(target=warm_up, args=((setup.planner, setup.planner_name), setup.problem, setup.log),
                              name="planner-warm-up", daemon=True)
    thread.start()
    while thread.is_alive() and not stop.is_set():
        yield tm.Wait(clock() + POLL_S)
