"""``python -m experiments``: see :mod:`experiments.run`; ``python -m experiments check``: see
:mod:`experiments.check`; ``python -m experiments operator``: see :mod:`experiments.operator`."""
import sys


def main(argv=None) -> int:
    """The experiments' command line on ``argv`` (``sys.argv[1:]`` when None)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["check"]:
        from experiments.check import main as check

        return check(argv[1:])
    if argv[:1] == ["operator"]:
        from experiments.operator import main as operator

        return operator(argv[1:])
    from experiments.run import main as run

    return run(argv)


if __name__ == "__main__":
    raise SystemExit(main())
