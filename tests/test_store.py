"""mission.db: append-only, one decision per stage, faithful replay, refuses another mission."""
from __future__ import annotations

import sqlite3

import pytest

from mission.ballot import Ballot
from storage.missiondb import MissionStore, StoreMismatch

META = {"mission": "tiny", "seed": 7, "planner": "ssap"}


def test_replay_returns_what_was_recorded(tmp_path):
    store = MissionStore(tmp_path / "mission.db", META)
    assert store.observation("a", 0, 5, (1.0, 2.0), t=0.0)
    assert not store.observation("a", 0, 9, (9.0, 9.0), t=0.0)  # the first report stands
    store.missing(0, ["b"])
    store.event("hello", "a", 0, pid=11, host="h1")
    store.decision(0, ["a"], 3.5)
    assert store.confirmation("a", 0, True, "deployed", (1.0, 2.0), 4.0)
    assert not store.confirmation("a", 0, False, "late", (1.0, 2.0), 4.0)
    store.observation("a", 1, 2, (3.0, 2.0))
    store.observation("b", 1, None, (0.0, 0.0))
    store.close()

    store = MissionStore(tmp_path / "mission.db", META)
    rec = store.replay()
    assert store.existed
    assert rec.observations == {("a", 0): 5, ("b", 0): None, ("a", 1): 2, ("b", 1): None}
    assert rec.positions[("a", 0)] == (1.0, 2.0)
    assert rec.decisions == {0: (("a",), 3.5)}
    assert rec.confirmations == {("a", 0): (True, "deployed", (1.0, 2.0))}
    assert rec.carriers_info == {"a": {"pid": 11, "host": "h1"}}
    assert rec.next_stage == 1 and not rec.ended
    assert store.latencies_ms() == [4.0]
    assert store.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    store.close()


def test_a_stage_is_decided_once(tmp_path):
    store = MissionStore(tmp_path / "m.db", META)
    store.decision(0, [], 1.0)
    with pytest.raises(sqlite3.IntegrityError):
        store.decision(0, ["a"], 1.0)
    # The failed attempt left no trace.
    assert store.db.execute("SELECT COUNT(*) FROM events WHERE kind='decision'").fetchone()[0] == 1
    assert store.replay().decisions == {0: ((), 1.0)}


def test_a_batch_commits_once_and_keeps_each_write_atomic(tmp_path):
    """What the coordinator holds while it drains its inbox: the writes of a batch are invisible
    to a reader until the batch ends (or flush), a failing write inside it leaves no trace and
    spoils nothing else, ``then`` callbacks run only once their write is committed, and the file
    holds exactly what the same writes one by one would have written."""
    from mission import events as ev
    from mission import state as ms

    def rows(path):
        with sqlite3.connect(path) as db:
            return db.execute("SELECT kind, carrier, stage, payload FROM events WHERE kind != 'open'").fetchall()

    def writes(store):
        assert store.observation("a", 0, 5, (1.0, 2.0), t=0.0, wall_time=1.0)
        assert not store.observation("a", 0, 9, (9.0, 9.0), t=0.0, wall_time=1.5)
        store.decision(0, ["a"], 3.5, wall_time=2.0)
        with pytest.raises(sqlite3.IntegrityError):
            store.decision(0, [], 1.0, wall_time=2.5)
        store.event("hello", "b", 0, wall_time=3.0, pid=1, host="h")

    one_by_one = MissionStore(tmp_path / "plain.db", META)
    writes(one_by_one)
    one_by_one.close()

    store = MissionStore(tmp_path / "batched.db", META)
    committed = []
    with store.batch():
        writes(store)
        store.record(ms.Record(ev.Bye("b", (), (), "end", 4.0), None), None, then=committed.append)
        assert committed == [] and [k for k, *_ in rows(tmp_path / "batched.db")] == []  # nothing visible yet
        store.flush()
        assert len(committed) == 1 and len(rows(tmp_path / "batched.db")) == 4
        store.event("end", None, 1, wall_time=5.0, reason="complete")
    assert rows(tmp_path / "batched.db")[:3] == rows(tmp_path / "plain.db")
    assert [k for k, *_ in rows(tmp_path / "batched.db")] == ["observation", "decision", "hello", "bye", "end"]
    assert store.replay().decisions == {0: (("a",), 3.5)}
    store.close()


def test_events_are_append_only(tmp_path):
    store = MissionStore(tmp_path / "m.db", META)
    store.event("end", None, 3, reason="complete")
    with pytest.raises(sqlite3.DatabaseError, match="append-only"):
        store.db.execute("UPDATE events SET kind='x'")
    with pytest.raises(sqlite3.DatabaseError, match="append-only"):
        store.db.execute("DELETE FROM events")
    assert store.replay().ended


def test_refuses_another_mission(tmp_path):
    MissionStore(tmp_path / "m.db", META).close()
    with pytest.raises(StoreMismatch, match="seed"):
        MissionStore(tmp_path / "m.db", dict(META, seed=8))


def test_survives_a_killed_writer(tmp_path):
    """Committed rows are durable even if the writing process dies without closing."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(__import__('pathlib').Path(__file__).resolve().parents[1])!r})
        from storage.missiondb import MissionStore
        s = MissionStore({str(tmp_path / 'k.db')!r}, {META!r})
        s.observation("a", 0, 4, (0.0, 0.0))
        s.decision(0, ["a"], 1.0)
        os.kill(os.getpid(), 9)
    """)
    proc = subprocess.run([sys.executable, "-c", code], timeout=60)
    assert proc.returncode == -9
    rec = MissionStore(tmp_path / "k.db", META).replay()
    assert rec.decisions == {0: (("a",), 1.0)} and rec.observations == {("a", 0): 4}


def test_epochs_grow_with_every_open_and_a_newer_one_on_the_same_file_is_seen(tmp_path):
    """docs/protocol.md, "Epochs": 1 for a fresh mission, one more at every reopening, at least
    the floor a standby learnt; a store sees a newer epoch opened on its file by another process
    (a standby on the same disk), once, and never its own."""
    from storage.missiondb import highest_epoch

    path = tmp_path / "mission.db"
    assert highest_epoch(path) == 0
    first = MissionStore(path, META, coordinator="coordinator")
    assert first.epoch == 1 and first.newer_ballot() is None
    first.event("rejected", reason="x", detail="y")
    second = MissionStore(path, META, coordinator="standby")  # the standby, while the first still runs
    assert second.epoch == 2 and second.newer_ballot() is None and second.ballot == Ballot(2, "standby")
    assert first.newer_ballot() == Ballot(2, "standby") and first.newer_ballot() is None  # rows seen are not read again
    second.close()
    first.close()
    third = MissionStore(path, META, min_epoch=7)
    assert third.epoch == 7 and highest_epoch(path) == 7
    third.close()
    assert MissionStore(path, META).epoch == 8


def test_a_decision_of_an_older_epoch_is_fenced_in_its_own_transaction(tmp_path):
    """A coordinator that checked its epoch, then paused while a standby opened the same file:
    its decision's write is refused under the write lock, and nothing of it is written."""
    from storage.missiondb import StoreFenced

    path = tmp_path / "mission.db"
    first = MissionStore(path, META)
    first.decision(0, ["a"], 1.0)
    second = MissionStore(path, META)
    with pytest.raises(StoreFenced, match="epoch 2") as raised:
        first.decision(1, ["b"], 1.0, missing=["c"])
    assert raised.value.epoch == 2 and raised.value.ballot == Ballot(2)
    second.decision(1, ["c"], 2.0)
    assert second.replay().decisions == {0: (("a",), 1.0), 1: (("c",), 2.0)}
    assert ("c", 1) not in second.replay().observations
    first.close()
    second.close()
