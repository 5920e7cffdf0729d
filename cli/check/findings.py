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

    def section(self, title: str) -> None:
        self.say(title)

    def info(self, text: str) -> None:
        self.say(f"  {text}")

    def problem(self, subject: str, found: str, todo: str = "") -> None:
        p = Problem(subject, found, todo)
        self.problems.append(p)
        self.say(f"  PROBLEM {p.line()}")

    @property
    def ok(self) -> bool:
        return not self.problems
