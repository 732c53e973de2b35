"""``python -m recording rebuild RUN_DIR``: write RUN_DIR/mission.mcap from RUN_DIR/mission.db.

    python -m recording rebuild runs/six_carriers-20260101-120000
    python -m recording rebuild RUN_DIR --scenario scenarios/six_carriers.yaml -o /tmp/m.mcap
    python -m recording rebuild RUN_DIR --profile ros2      # RUN_DIR/ros2bag, for ros2 bag play

Exit codes: 0 written, 2 bad input (no mission.db, no scenario file).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))


def main(argv=None) -> int:
    from recording import PROFILES

    p = argparse.ArgumentParser(prog="python -m recording", description="Mission recordings (MCAP).")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("rebuild", help="rebuild mission.mcap from mission.db (and the scenario's trajectories)")
    r.add_argument("run_dir", help="a results directory holding mission.db")
    r.add_argument("--scenario", help="the scenario file (default: summary.json's scenario_file)")
    r.add_argument("-o", "--out", help="output file (default RUN_DIR/mission.mcap; ros2: the bag directory RUN_DIR/ros2bag)")
    r.add_argument("--profile", choices=PROFILES, default=PROFILES[0],
                   help="foxglove (default): Foxglove's schemas; ros2: a rosbag2 bag of ROS 2 messages (needs .[ros2])")
    r.add_argument("--pose-interval", type=float, default=None, metavar="SECONDS",
                   help="poses every this many simulated seconds (0 = none; default: what an unpaced mission's "
                        "carriers send, run_fleet.py's --pose-interval)")
    args = p.parse_args(argv)
    from recording.rebuild import rebuild

    try:
        path = rebuild(args.run_dir, args.scenario, args.out, args.pose_interval, args.profile)
    except ImportError as exc:
        print(f"python -m recording: the ros2 profile needs rosbags: pip install -e '.[ros2]' ({exc})", file=sys.stderr)
        return 2
    except (FileNotFoundError, ValueError) as exc:
        print(f"python -m recording: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
