"""tools/profile_view_kernel.py: samples are charged to the innermost loop around them."""

from __future__ import annotations

from tool_scripts import load_tool


def _tool():
    return load_tool("profile_view_kernel")


def test_samples_go_to_the_innermost_loop():
    """An inner loop (4–8) inside an outer one (0–16): the outer is charged only what lies
    outside the inner; a forward jump and a jump farther back than the limit close no loop,
    and samples outside every loop are charged to none."""
    listing = [(0, "nop"), (4, "add"), (8, "jne 0x4"), (12, "jae 0x20"), (16, "jne 0x0"),
               (20, "ret"), (800, "jmp 0x0")]
    samples = {0: 1, 4: 3, 8: 2, 12: 5, 16: 0, 20: 7, 800: 9}
    got = _tool().loops(samples, listing, max_bytes=600)
    assert got == [(6, 0, 16), (5, 4, 8)]
