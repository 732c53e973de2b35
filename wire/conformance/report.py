"""The kit's report: one line per rule, the verdict, the exit status."""
from __future__ import annotations

from pathlib import Path

from .rules import RULES, Result


def table(results: list[Result], rules: tuple = RULES) -> str:
    """One line per rule: id, times exercised, ``pass`` / ``FAIL`` / ``-``, and the first failure
    (or what the rule says and its section of docs/protocol.md); ``rules``: the kit's table
    (the carrier kit's by default)."""
    sections = {rule: (section, text) for rule, section, text in rules}
    lines = [f"{'rule':<24} {'n':>4}  result  detail", "-" * 78]
    for r in results:
        section, text = sections[r.rule]
        lines.append(f"{r.rule:<24} {r.exercised:>4}  {r.status:<6}  {r.failure or text + ' (' + section + ')'}")
    return "\n".join(lines)


def passed(results: list[Result]) -> bool:
    """Every exercised rule passed, and at least one was exercised."""
    return all(r.failure is None for r in results) and any(r.exercised for r in results)


def verdict(results: list[Result], carrier: str, exit_code: int | None, workdir: Path) -> str:
    """The report's last line."""
    return (f"conformance: {'PASS' if passed(results) else 'FAIL'} (carrier {carrier}, exit code {exit_code}; "
            f"logs in {workdir})")
