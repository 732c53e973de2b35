"""``run_fleet.py SCENARIO --role report --out DIR``: a mission's results from whatever logs exist
in DIR, so a mission whose coordinator died still gets them (docs/fleet.md, "Report").

Reads DIR/mission.db (the coordinator's events, if present) and every carrier log
DIR/carriers/*.db (storage/carrierlog.py), merges them with the live coordinator's fold
(:func:`mission.report.merge`) and writes DIR/summary.json (``mission.summary.summary``, the
coordinator's function, annotated with where each deployment came from), DIR/merged_log.jsonl
and DIR/map.png (coordinator/results.py, the coordinator's drawing). A summary.json the
coordinator wrote is kept as DIR/summary.coordinator.json before it is replaced; the report's
own carries a ``report`` section (inputs, skipped logs, conflicts), so a later report keeps
the first copy.

Inputs of another mission: mission.db is the mission's own record, so one of another mission
(mission id, scenario, fingerprint or seed differ) **refuses** the report (:class:`ReportError`,
exit 2: nothing is written); a carrier log of another mission, or of a carrier not in the
scenario, is **skipped** with a one-line warning (listed in summary.json's ``report.skipped``):
the others still make the results. An unreadable file refuses the report.
"""
from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass
from pathlib import Path

from mission.report import CarrierRecord, Merged, annotate, merge
from planner.settings import ONBOARD_PLANNER

#: Where the merged mission log goes in the results directory.
MERGED_LOG = "merged_log.jsonl"
#: Where the report keeps the coordinator's own summary.json before replacing it.
COORDINATOR_SUMMARY = "summary.coordinator.json"
#: The on-board planner named in summary.json when there is no mission.db and the logs do not
#: name theirs (carriers decide with it when no coordinator is reachable).
#: mission.db meta keys (coordinator/node.py writes them) a report checks, and carrier log keys.
DB_IDENTITY = ("mission", "scenario", "seed", "fingerprint")  # the actionable differences first
LOG_IDENTITY = ("mission", "seed", "fingerprint")


class ReportError(RuntimeError):
    """The report cannot be made: one line naming the file."""


@dataclass(frozen=True)
class Report:
    """What :func:`run_report` wrote.

    Attributes:
        summary: the summary.json dict.
        merged: the merge (state, sources, conflicts).
        files: the files written, in DIR.
        skipped: one line per carrier log not merged.
    """

    summary: dict
    merged: Merged
    files: tuple[Path, ...]
    skipped: tuple[str, ...]

    def line(self, out: Path) -> str:
        """The one line ``--role report`` prints."""
        s, m = self.summary, self.merged
        deps = [d for c in s["carriers"] for d in c["deployments"]]
        own = sum(1 for d in deps if d.get("by") == "carrier")
        inputs = ([m.db_source] if m.db_source else []) + [f"{len(m.logs)} carrier log(s)"]
        return (f"report: total reward {s['total_reward']:.3f} (features {s['total_features']:.1f}), "
                f"{len(deps)} deployment(s) ({own} decided by carriers), {s['stages_decided']}/{s['stages']} "
                f"stage(s) decided by the coordinator, {len(m.conflicts)} conflict(s); from "
                f"{' + '.join(inputs)}; results: " + ", ".join(str(out / f.name) for f in self.files))


def _identity(scenario, mission: str | None, seed: int | None):
    """(scenario with the seed, mission id, fingerprint) of this report."""
    from wire import keys
    from wire.messages import scenario_fingerprint

    if seed is not None:
        scenario = scenario.with_seed(int(seed))
    mission = keys.check_id(mission or keys.mission_id_from_name(scenario.name), "mission")
    return scenario, mission, scenario_fingerprint(scenario)


#: Meta keys without which a log cannot be told to be of this mission.
REQUIRED = ("mission", "fingerprint")


def _mismatch(meta: dict, wanted: dict, keys) -> str | None:
    for key in REQUIRED:
        if key not in meta:
            return f"no {key} in its meta: cannot tell its mission"
    for key in keys:
        if key in meta and meta[key] != wanted[key]:
            flag = {"seed": " (pass --seed)", "mission": " (pass --mission)"}.get(key, "")
            return f"{key} is {meta[key]!r}, this report has {wanted[key]!r}{flag}"
    return None


def read_inputs(out: Path, scenario, mission: str, fingerprint: str, spec_carriers):
    """(mission.db events or None, its meta, carrier records, skipped lines) from ``out``.

    Raises:
        ReportError: no results directory, nothing to read, an unreadable file, or a mission.db
            of another mission.
    """
    from storage.carrierlog import read_log
    from storage.missiondb import load_events, load_meta

    if not out.is_dir():
        raise ReportError(f"{out}: no such results directory")
    db_path = out / "mission.db"
    logs = sorted((out / "carriers").glob("*.db")) if (out / "carriers").is_dir() else []
    if not db_path.exists() and not logs:
        raise ReportError(f"{out}: no mission.db and no carrier logs (carriers/*.db): nothing to report")
    wanted = {"mission": mission, "scenario": scenario.name, "fingerprint": fingerprint, "seed": int(scenario.seed)}
    events, db_meta = None, {}
    if db_path.exists():
        try:
            db_meta = load_meta(db_path)
            events = load_events(db_path)
        except (sqlite3.Error, OSError, ValueError, KeyError, TypeError) as exc:
            raise ReportError(f"{db_path}: cannot read it as a mission log: {type(exc).__name__}: {exc}") from None
        bad = _mismatch(db_meta, wanted, DB_IDENTITY)
        if bad:
            raise ReportError(f"{db_path}: holds another mission ({bad})")
    records, skipped = [], []
    for path in logs:
        name = f"carriers/{path.name}"
        try:
            meta, entries = read_log(path)
        except (sqlite3.Error, OSError, ValueError, TypeError) as exc:
            raise ReportError(f"{path}: cannot read it as a carrier log: {type(exc).__name__}: {exc}") from None
        cid = meta.get("carrier")
        bad = _mismatch(meta, wanted, LOG_IDENTITY)
        if cid != path.stem:
            bad = f"its meta names carrier {cid!r}, its file name {path.stem!r}"
        elif cid not in spec_carriers:
            bad = f"carrier {cid!r} is not in the scenario"
        if bad:
            skipped.append(f"{path}: skipped, another mission's log ({bad})")
            continue
        records.append(CarrierRecord(cid, name, meta, tuple(entries)))
    return events, db_meta, records, skipped


def _previous_summary(out: Path, mission: str, seed: int) -> dict:
    """The summary.json already in ``out`` (the coordinator's, or an earlier report's) when it is
    of this mission: its process facts (pid, host, wall time, rejection counts) are kept."""
    try:
        data = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) and data.get("mission") == mission and data.get("seed") == seed else {}


def run_report(scenario, out, mission: str | None = None, seed: int | None = None, scenario_path: str = "",
               render: bool = True, log=print) -> Report:
    """Merge the logs in ``out`` and write summary.json, merged_log.jsonl and (``render``)
    map.png there. ``log`` gets one line per skipped log and per problem drawing the map.

    Raises:
        ReportError: the report cannot be made (nothing is written).
    """
    from world import build_problem
    from coordinator.results import render_map, result_line, write_json
    from mission.coverage import spec_options
    from mission.state import MissionSpec
    from mission.summary import RunInfo, summary as mission_summary

    out = Path(out)
    scenario, mission, fingerprint = _identity(scenario, mission, seed)
    problem = build_problem(scenario)
    spec = MissionSpec.build(scenario.carrier_ids, problem.valid, problem.passengers, scenario.stage_times(),
                             fingerprint, **spec_options(problem))
    events, db_meta, records, skipped = read_inputs(out, scenario, mission, fingerprint, set(spec.carriers))
    for line in skipped:
        log(line)
    if events is None and not records:
        raise ReportError(f"{out}: no mission.db and no carrier log of this mission: nothing to report")
    merged = merge(spec, events or (), records, db_source="mission.db" if events is not None else None)

    previous = _previous_summary(out, mission, int(scenario.seed))
    if db_meta:
        planner, options = db_meta.get("planner"), db_meta.get("planner_options", {})
    else:
        named = {rec.meta.get("planner") for rec in records} - {None}
        planner, options = (named.pop() if len(named) == 1 else ONBOARD_PLANNER), {}
    coordinator = previous.get("coordinator") or {}
    rejected = (previous.get("rejected") or {}).get("coordinator") or {}
    run = RunInfo(scenario=scenario.name, scenario_file=str(scenario_path or previous.get("scenario_file")
                                                            or scenario.source),
                  mission=mission, planner=str(planner), planner_options=dict(options or {}),
                  seed=int(scenario.seed), pid=coordinator.get("pid"), host=coordinator.get("host"),
                  wall_time_s=float(previous.get("wall_time_s") or 0.0), rejected=dict(rejected),
                  passenger_types=tuple(c.passenger_types for c in scenario.carriers))
    x_now = [[None if v != v else float(v) for v in row] for row in merged.state.observations()]
    reuse = previous.get("clairvoyant") if previous.get("observations") == x_now else None
    data = mission_summary(merged.state, problem, run, bound=reuse is None)
    if reuse is not None:
        data["clairvoyant"] = reuse  # a function of the observations alone, computed already
        if previous.get("upper_bound") is not None:  # likewise (of the instance and the seed)
            data["upper_bound"] = previous["upper_bound"]
    data = annotate(data, merged)
    if events is not None:  # the epoch of the last coordinator on record, as its own summary says
        from storage.missiondb import highest_epoch

        data["epoch"] = highest_epoch(out / "mission.db")
    # What only the coordinator knew: the stages its planner failed (also in mission.db) and the
    # denials with their senders; kept from its own summary.
    for key in ("planner_faults", "denials"):
        if key in previous:
            data[key] = previous[key]
    data["report"] = {
        "inputs": (["mission.db"] if merged.db_source else []) + [rec.source for rec in records],
        "skipped": list(skipped), "conflicts": [c.line() for c in merged.conflicts],
        "adds_to_mission_db": sorted([cid, j] for cid, j in merged.added) if merged.db_source else None,
        "merge_rule": "mission.db's events folded, then each carrier log's outcomes: a Confirm when the "
                      "coordinator's decision is on record, else the carrier's account (docs/fleet.md, \"Report\")",
    }
    files = [out / "summary.json", out / MERGED_LOG]
    if previous and "report" not in previous:  # the coordinator's own: kept, never lost
        write_json(out / COORDINATOR_SUMMARY, previous)
        files.append(out / COORDINATOR_SUMMARY)
    write_json(out / "summary.json", data)
    tmp = out / (MERGED_LOG + ".tmp")
    tmp.write_text("".join(json.dumps(row, sort_keys=False) + "\n" for row in merged.rows()))
    tmp.replace(out / MERGED_LOG)
    if render:
        try:
            render_map(scenario, merged.state, out / "map.png", trails=merged.trails(),
                       title=f"{scenario.name}: {planner}, seed {scenario.seed} (report)\n{result_line(data)}")
            files.append(out / "map.png")
        except Exception as exc:
            log(f"report: map.png not drawn: {type(exc).__name__}: {exc}")
    return Report(data, merged, tuple(files), tuple(skipped))
