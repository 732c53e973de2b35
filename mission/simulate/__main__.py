"""``python -m mission.simulate``: the command line (:mod:`launcher.simulate`; mission/ has none)."""

if __name__ == "__main__":
    from launcher.simulate import main

    raise SystemExit(main())
