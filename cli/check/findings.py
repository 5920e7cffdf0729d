"""What ``fluidsense check`` found: lines for the person at the cell as they come, and
the problems, each with what to do, kept for the summary and the exit code."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Problem:
    subject: str  # what it is about: "p_act", "valve supply (output 0)", "sampling"
    found: str
    todo: str

    def line(self) -> str:
        return f"{self.subject}: {self.found}" + (f"; {self.todo}" if self.todo else "")


class Findings:
    """``say`` prints a line (the CLI gives ``print``; library code never prints)."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.say = say
        self.problems: list[Problem] = []
        self.warnings: list[str] = []

    def section(self, title: str) -> None:
        self.say(title)

    def info(self, text: str) -> None:
        self.say(f"  {text}")

    def problem(self, subject: str, found: str, todo: str = "") -> None:
        p = Problem(subject, found, todo)
        self.problems.append(p)
        self.say(f"  PROBLEM {p.line()}")

    def warning(self, text: str) -> None:
        """Said and repeated in the summary, but not a problem: the cell is as configured
        (a deliberate choice such as a cell without a vent path on a dead link)."""
        self.warnings.append(text)
        self.say(f"  WARNING {text}")

    @property
    def ok(self) -> bool:
        return not self.problems
