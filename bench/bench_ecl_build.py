"""ECL generation of every shipped platform: one process per core against one process.

Both runs generate the same rows (checked) in this process's run, back to back, so the
machine's load hits both alike; the ratio parallel / serial is what the process pool buys
(ideal: 1 / cores, plus spawning each worker and compiling its models once). Nothing is
written: the shipped databanks stay as they are.
"""

from __future__ import annotations

import time

from kinesphere.platforms.platform import platform_names
from kinesphere.services.ecl.parallel import default_workers, generate_many


def main() -> None:
    names = platform_names()
    workers = default_workers()
    start = time.perf_counter()
    serial = generate_many(names, workers=1)
    serial_s = time.perf_counter() - start
    start = time.perf_counter()
    parallel = generate_many(names, workers=workers)
    parallel_s = time.perf_counter() - start
    same = all(serial[n].rows == parallel[n].rows for n in names)
    rows = sum(len(b.rows) for b in serial.values())
    print(f"ecl build --all, {len(names)} platforms, {rows} rows (identical: {same})")
    print(f"  serial (1 process)      {serial_s:7.1f} s")
    print(f"  parallel ({workers} processes) {parallel_s:7.1f} s  = {parallel_s / serial_s:.2f}x "
          f"serial (ideal {1 / workers:.2f}x)")
    if not same:
        raise SystemExit("parallel generation gave other rows than serial generation")
