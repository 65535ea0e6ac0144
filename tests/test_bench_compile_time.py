"""benchmarks.compile_time: what it reports from the halves' compile times."""

from __future__ import annotations


def test_compile_time_names_the_kernels_both_halves_compile():
    from benchmarks.compile_time import compiled_twice

    halves = {
        "raster": {"kernels": {"a.k": 3.0, "b.edi": 2.0, "c.tiny": 0.01}},
        "losses": {"kernels": {"b.edi": 1.5, "d.ssim": 4.0, "c.tiny": 0.2}},
    }
    assert compiled_twice(halves) == ["b.edi"]  # c.tiny is below the floor in one half
    assert compiled_twice({}) == []
