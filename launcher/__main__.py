"""``python -m launcher``: the launcher (launcher/main.py); the one-host supervisor's children
run this way."""
import sys

from launcher.main import main

sys.exit(main(prog="python -m launcher"))
