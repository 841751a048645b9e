"""Do Warp CPU launches release the GIL, and do two of them run at once? (issue #42 item 4: one cloth on
every core.)

Three probes on a busy kernel (each of 1000 threads iterates ``sin``):

1. serial: two long launches one after the other, then the same two from two Python threads (wall and
   the process's CPU time over wall: 2 where both cores ran it, 1 where one did);
2. Python beside a launch: how many iterations a Python loop in the main thread makes while another thread
   is inside a long launch (none if the launch held the GIL);
3. a short launch beside a long one: its wall time, and whether the long one was still running when it
   returned (no Warp lock serialises launches).

Warp calls a CPU kernel through a ``ctypes.CFUNCTYPE`` pointer, which releases the GIL for the call. Run
on both cores (``taskset -c 0-1``); on a shared box read (1) with the load average it prints.

    taskset -c 0-1 .venv/bin/python benchmarks/bench_cpu_threads.py
"""

from __future__ import annotations

import json
import os
import threading
import time

import warp as wp


@wp.kernel
def _busy(a: wp.array(dtype=float), iters: int):
    i = wp.tid()
    x = a[i]
    for _ in range(iters):
        x = wp.sin(x) + 1.0e-3
    a[i] = x


def main() -> None:
    wp.config.quiet = True
    a, b = wp.zeros(1000, dtype=float), wp.zeros(1000, dtype=float)
    wp.launch(_busy, 1000, [a, 10])  # compile
    long_iters = 20000

    def run(arr: wp.array, iters: int = long_iters) -> None:
        wp.launch(_busy, 1000, [arr, iters])

    t = time.perf_counter()
    run(a)
    run(b)
    serial = time.perf_counter() - t
    threads = [threading.Thread(target=run, args=(x,)) for x in (a, b)]
    t, c = time.perf_counter(), time.process_time()
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    both, cpu = time.perf_counter() - t, time.process_time() - c

    done = threading.Event()

    def worker() -> None:
        run(a)
        done.set()

    th = threading.Thread(target=worker)
    th.start()
    time.sleep(0.01)  # let the worker enter its launch
    count, t = 0, time.perf_counter()
    while not done.is_set():
        count += 1
    beside = time.perf_counter() - t
    th.join()

    t = time.perf_counter()
    run(b, long_iters // 50)
    short_alone = time.perf_counter() - t
    done.clear()
    th = threading.Thread(target=worker)
    th.start()
    time.sleep(0.01)
    t = time.perf_counter()
    run(b, long_iters // 50)
    short_beside = time.perf_counter() - t
    long_still_running = not done.is_set()
    th.join()
    print(
        json.dumps(
            {
                "cpus_allowed": len(os.sched_getaffinity(0)),
                "load_avg_1min": round(os.getloadavg()[0], 2),
                "serial_s": round(serial, 3),
                "two_threads_s": round(both, 3),
                "speedup": round(serial / both, 2),
                "cpu_over_wall_two_threads": round(cpu / both, 2),
                "python_iterations_beside_launch": count,
                "launch_s": round(beside, 3),
                "short_launch_alone_s": round(short_alone, 4),
                "short_launch_beside_long_s": round(short_beside, 4),
                "long_launch_still_running": long_still_running,
            }
        )
    )


if __name__ == "__main__":
    main()
