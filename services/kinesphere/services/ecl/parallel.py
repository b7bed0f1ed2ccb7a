"""Generation on every core: one job per (platform, VSAM entry), rows assembled in VSAM order.

Each (limb, origin) pair is generated independently of the others (its own solver, its own
model data), so the jobs can run in any order on any process and the assembled rows are the
same as a serial run's, byte for byte. Jobs go out longest first (by joints x pulls) so the
last one to finish is short. Worker processes are spawned, not forked: the parent may run a
progress thread, and a forked child would inherit its locks.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass

from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import load_platform
from kinesphere.services.ecl.generate import (
    GENERATOR_VERSION,
    EntryReport,
    GenerationReport,
    generate_entry,
    pulls,
)
from kinesphere.services.ecl.store import PoseRow
from kinesphere.services.ecl.vsam import load_vsam

Done = Callable[[str, EntryReport, int, int], None]
"""done(platform, entry report, jobs finished, jobs in all): called as each job finishes."""


@dataclass(frozen=True)
class Job:
    platform: str
    limb: str
    origin: str
    cost: int  # joints x pulls: a rough guess of the job's length


@dataclass
class Built:
    """One platform's generated rows and report, in VSAM entry order."""

    rows: list[PoseRow]
    report: GenerationReport


def default_workers() -> int:
    """One process per core the scheduler gives us."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on every OS
        return max(1, os.cpu_count() or 1)


def jobs(platforms: Iterable[str], limbs: tuple[str, ...] = ()) -> list[Job]:
    """Every (limb, origin) entry of the platforms (only ``limbs``' when given: labels or
    aliases), longest first (ties in VSAM order)."""
    out: list[Job] = []
    for name in platforms:
        plat = load_platform(name)
        vsam = load_vsam(plat)
        wanted = {plat.eurdf.limb(x).name for x in limbs}
        entries = [e for e in vsam.entries if not e.is_core and (not limbs or e.limb in wanted)]
        if limbs and not entries:  # a base-only platform (Khepera) has none: core rows only
            raise KinesphereError("unknown_limb", f"{plat.name}: no VSAM entry for "
                                  f"{', '.join(limbs)} in {plat.vsam_path}")
        for entry in entries:
            if not entry.is_core:
                cost = len(plat.eurdf.limb_joints(entry.limb)) * len(pulls(entry))
                out.append(Job(name, entry.limb, entry.origin, cost))
    return sorted(out, key=lambda j: -j.cost)


def generate_many(platforms: list[str], workers: int | None = None,
                  done: Done | None = None, limbs: tuple[str, ...] = ()) -> dict[str, Built]:
    """Generate every platform's rows (only ``limbs``' entries when given) with ``workers``
    processes (1: in this process)."""
    todo = jobs(platforms, limbs)
    results: dict[Job, tuple[list[PoseRow], EntryReport, float]] = {}
    workers = default_workers() if workers is None else max(1, workers)
    if workers == 1 or not todo:
        for job in todo:
            results[job] = _run(job)
            if done is not None:
                done(job.platform, results[job][1], len(results), len(todo))
    else:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(workers, len(todo)),
                                 mp_context=context) as pool:
            futures: dict[Future[tuple[list[PoseRow], EntryReport, float]], Job] = {
                pool.submit(_run, job): job for job in todo
            }
            for future in as_completed(futures):
                job = futures[future]
                results[job] = future.result()
                if done is not None:
                    done(job.platform, results[job][1], len(results), len(todo))
    return {name: _assemble(name, results) for name in platforms}


def _run(job: Job) -> tuple[list[PoseRow], EntryReport, float]:
    start = time.perf_counter()
    rows, report = generate_entry(job.platform, job.limb, job.origin)
    return rows, report, time.perf_counter() - start


def _assemble(name: str, results: dict[Job, tuple[list[PoseRow], EntryReport, float]]
              ) -> Built:
    plat = load_platform(name)
    mine = {(j.limb, j.origin): r for j, r in results.items() if j.platform == name}
    rows: list[PoseRow] = []
    reports: list[EntryReport] = []
    seconds = 0.0
    for entry in load_vsam(plat).entries:
        if (entry.limb, entry.origin) not in mine:
            continue  # a core entry, or a limb left out
        entry_rows, report, took = mine[(entry.limb, entry.origin)]
        rows.extend(entry_rows)
        reports.append(report)
        seconds += took
    return Built(rows, GenerationReport(plat.name, GENERATOR_VERSION, reports, len(rows),
                                        seconds))
