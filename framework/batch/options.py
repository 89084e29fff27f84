"""What a batch is asked to do (:class:`BatchOptions`) and what it returns (:class:`BatchResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

EXIT_OK, EXIT_FAILED = 0, 1


@dataclass
class BatchOptions:
    """What ``rigslim batch`` was asked to do (see :func:`add_parser` for each option)."""

    template: Path
    assets: list[str]
    out: Path
    workers: int | None = None
    threads_per_worker: int = 1
    scheduler: str | None = None
    memory_limit: str | None = None
    retries: int = 2
    timeout: float | None = None
    force: bool = False
    dashboard: bool = True


@dataclass
class BatchResult:
    rows: list[dict]
    seconds: float
    dashboard: str | None = None
    cluster: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict[str, int]:
        c = {"ok": 0, "skipped": 0, "failed": 0}
        for r in self.rows:
            c[r["status"]] = c.get(r["status"], 0) + 1
        return c

    @property
    def exit_code(self) -> int:
        return EXIT_FAILED if self.counts["failed"] else EXIT_OK
