#!/usr/bin/env python3
"""Where one view's pixel integral spends its time, loop by loop.

Runs :func:`sim.transport.view_integral.view_forward` (every band of one view, one thread, the scene
``natural``) for a few seconds under Linux ``perf record -e cpu-clock`` (a software clock: it
samples where hardware counters are not available, as in most virtual machines), then
attributes the samples that fall in the compiled kernel to its innermost loops: the kernel's
machine code is read from memory at its address, disassembled with ``objdump``, and every
backward jump shorter than ``--loop-bytes`` closes a loop.  Each loop is printed with its share
of the kernel's samples and its first instructions, from which the loop in
``sim/transport/view_integral.py`` can be told (a ``vcvtps2pd`` and ``vminpd`` loop is stage 1's gaps, a
run of ``vfmadd…sd`` with four table loads stage 2's reads, and so on).

Samples are attributed to the instruction after the one that stalls, and an outer loop's own
instructions are counted apart from its inner loops': the shares rank the loops, they are not
exact costs.  Needs ``perf`` (Debian's ``linux-perf``) and ``objdump`` (``binutils``).

Usage::

    python3 tools/profile_view_kernel.py                   # paper, centre view (0), scene at 1x
    python3 tools/profile_view_kernel.py --scale 2 --seconds 30 --top 20
    python3 tools/profile_view_kernel.py --time-only --bands 13   # a pass's time, no profile
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Bytes of machine code read from the kernel's entry point (its code is ~40 KB on x86-64).
CODE_BYTES = 200_000


def run_kernel(preset: str, view: int, scale: int, seconds: float, info: Path | None,
               n_bands: int | None = None) -> None:
    """The worker (run under ``perf``): write the kernel's address and code to ``info`` (when
    given), then integrate the view again and again for ``seconds``; print the time a pass
    took on this thread (thread CPU time, best pass)."""
    import numpy as np

    from scenes.registry import get_scene
    from sim.transport import exact as transport, view_integral
    from sim.optics.design import get_design
    from sim.frame import FrameModel

    d = get_design(preset)
    L = d.wavelengths.size
    if n_bands is not None and not 1 <= n_bands <= L:
        sys.exit(f"--bands must be between 1 and {L}, got {n_bands}")
    if view not in d.views:
        sys.exit(f"--view must be one of the design's views {list(d.views)}, got {view}")
    tr = FrameModel(d, trace_seed=transport.SEEDS["scene"]).transport
    v = d.view_size_px
    bands = list(range(L if n_bands is None else n_bands))
    cube, _ = get_scene("natural", (scale * v, scale * v), d.wavelengths)
    f = np.ascontiguousarray(cube[:, :, bands], np.float32)
    tr.prepare(bands, f.shape[1])
    k = tr.views.index(view)
    # The blocks of rows a frame's threads take (Transport.view_blocks), one after another.
    _, blocks = tr.view_blocks(f, k, bands)

    def once():
        for block in blocks:
            block()

    once()
    if info is not None:
        addr = view_integral.kernel_address()
        code = info.with_suffix(".bin")
        code.write_bytes(ctypes.string_at(addr, CODE_BYTES))
        info.write_text(json.dumps({"address": addr, "code": str(code), "view": tr.views[k]}))
    t0, n, best = time.perf_counter(), 0, float("inf")
    while time.perf_counter() - t0 < seconds:
        t = time.thread_time()
        once()
        best = min(best, time.thread_time() - t)
        n += 1
    print(f"{n} passes of view {tr.views[k]} ({len(bands)} bands, scene at {scale}x): "
          f"best {best:.3f} s{' (under perf)' if info is not None else ''}", flush=True)


def loops(samples: dict[int, int], listing: list[tuple[int, str]], max_bytes: int):
    """Innermost loops (offset of the first and last instruction) with their samples: a
    backward jump at most ``max_bytes`` back closes one; nested ones are counted apart."""
    found = []
    for a, text in listing:
        m = re.match(r"j\w+\s+0x([0-9a-f]+)", text)
        if m:
            target = int(m.group(1), 16)
            if target <= a and a - target <= max_bytes:
                found.append((target, a))
    # Innermost first: a loop that holds another is charged only what lies outside it.
    found.sort(key=lambda r: r[1] - r[0])
    charged, out = set(), []
    for lo, hi in found:
        own = [a for a, _ in listing if lo <= a <= hi and a not in charged]
        charged.update(own)
        out.append((sum(samples.get(a, 0) for a in own), lo, hi))
    return sorted(out, reverse=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--view", type=int, default=0, help="design view number (0: the centre)")
    ap.add_argument("--scale", type=int, default=1, help="scene at this many times the view grid")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--bands", type=int, help="the first N bands only (default: all)")
    ap.add_argument("--time-only", action="store_true",
                    help="time the passes without perf (no profile)")
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--loop-bytes", type=int, default=600)
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker or a.time_only:
        run_kernel(a.preset, a.view, a.scale, a.seconds, a.worker, a.bands)
        return
    for tool in ("perf", "objdump"):
        if shutil.which(tool) is None:
            sys.exit(f"{tool} is not installed (Debian: linux-perf, binutils)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        info, data = tmp / "kernel.json", tmp / "perf.data"
        cmd = ["perf", "record", "-q", "-e", "cpu-clock", "-F", "5000", "-o", str(data), "--",
               sys.executable, __file__, "--worker", str(info), "--preset", a.preset,
               "--view", str(a.view), "--scale", str(a.scale), "--seconds", str(a.seconds)]
        if a.bands is not None:
            cmd += ["--bands", str(a.bands)]
        subprocess.run(cmd, check=True)
        meta = json.loads(info.read_text())
        base = int(meta["address"])
        ips = subprocess.run(["perf", "script", "-i", str(data), "-F", "ip"], check=True,
                             capture_output=True, text=True).stdout.split()
        samples = collections.Counter(int(ip, 16) - base for ip in ips
                                      if 0 <= int(ip, 16) - base < CODE_BYTES)
        dis = subprocess.run(["objdump", "-D", "-b", "binary", "-m", "i386:x86-64",
                              f"--adjust-vma={base:#x}", meta["code"]], check=True,
                             capture_output=True, text=True).stdout
    listing = []
    for line in dis.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(?:[0-9a-f]{2} )+\s*(.*)", line)
        if m:
            listing.append((int(m.group(1), 16), m.group(2).strip()))
    # Addresses in jumps are absolute: back to offsets from the entry point.
    listing = [(addr - base, re.sub(r"0x([0-9a-f]+)",
                                    lambda m: hex(int(m.group(1), 16) - base)
                                    if int(m.group(1), 16) >= base else m.group(0), text))
               for addr, text in listing]
    total = sum(samples.values())
    if not total:
        sys.exit("no samples fell in the kernel (perf not permitted here?)")
    print(f"{total} samples in the kernel (view {meta['view']}); its innermost loops:")
    text = dict(listing)
    for n, lo, hi in loops(samples, listing, a.loop_bytes)[:a.top]:
        body = [text[x] for x in sorted(text) if lo <= x <= hi]
        ops = [t.split()[0] for t in body if t]
        print(f"  {100 * n / total:5.1f} %  {lo:#7x}–{hi:#7x}, {len(body)} instructions: "
              f"{' '.join(ops[:12])}{' …' if len(ops) > 12 else ''}")


if __name__ == "__main__":
    main()
