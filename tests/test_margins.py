"""``benchmarks.margins``: ablation rows merged across files and the reference's margins paired per seed."""

import json

import pytest

from benchmarks import margins as M


def _row(setting, preset, seed, novel, deblur, steps=100):
    return {
        "setting": setting,
        "preset": preset,
        "seed": seed,
        "steps": steps,
        "test_refined_psnr": novel,
        "test_refined_ssim": novel / 100,
        "deblur_psnr": deblur,
        "deblur_ssim": deblur / 100,
    }


def _write(path, rows, seconds=600.0, argv=("--refine-iters", "150")):
    path.write_text(
        json.dumps(
            {
                "environment": {"date_utc": "2026-11-23T00:00:00+00:00", "commit": "abc"},
                "size": "small",
                "seconds": seconds,
                "iters": 1000000,
                "rows": rows,
                "argv": list(argv),
            }
        )
    )
    return str(path)


def test_margins_are_paired_per_seed_across_files(tmp_path):
    a = _write(
        tmp_path / "a.json",
        [
            _row("noisy", "ebad", 0, 26.0, 27.0),
            _row("noisy", "ebad", 1, 27.0, 27.5),
            _row("noisy", "ebad", 2, 25.0, 26.0),
        ],
    )
    b = _write(
        tmp_path / "b.json",
        [
            _row("noisy", "bad", 0, 24.0, 23.0),
            _row("noisy", "bad", 2, 24.5, 23.5),
            _row("noisy", "3dgs", 0, 20.0, 20.0),
            _row("noisy", "3dgs", 1, 19.0, 19.5),
            _row("noisy", "3dgs-po", 0, 20.5, 20.0),
            _row("noisy", "3dgs-po", 1, 19.2, 19.0),
        ],
    )
    rows, headers = M.load_rows([a, b])
    assert [h["name"] for h in headers] == ["a", "b"]
    out = M.paired_margins(rows, "ebad")["noisy"]
    # bad ran seeds 0 and 2 only: ebad's seed 1 has no partner and is left out of the pairing
    m = out["bad"]["margin"]["test_refined_psnr"]
    assert m["seeds"] == [0, 2]
    assert m["per_seed"] == pytest.approx({0: 2.0, 2: 0.5})
    assert m["mean"] == pytest.approx(1.25)
    assert out["bad"]["margin"]["deblur_psnr"]["per_seed"] == pytest.approx({0: 4.0, 2: 2.5})
    # the stronger 3dgs by mean novel PSNR: 3dgs-po (19.85) over 3dgs (19.5)
    assert out["3dgs-po"]["stronger_3dgs"] and not out["3dgs"]["stronger_3dgs"]
    assert out["ebad"]["test_refined_psnr"] == pytest.approx((26.0, (2 / 3) ** 0.5))
    assert "margin" not in out["ebad"]
    text = M.table({"noisy": out}, "ebad")
    assert "`3dgs-po` (the stronger 3dgs)" in text and "+1.25 (+2.00, +0.50)" in text
    M.plot({"noisy": out}, "ebad", tmp_path / "m.png", "title")
    assert (tmp_path / "m.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_row_found_twice_names_both_files(tmp_path):
    a = _write(tmp_path / "a.json", [_row("sfm", "ebad", 0, 26.0, 27.0)])
    b = _write(tmp_path / "b.json", [_row("sfm", "ebad", 0, 25.0, 27.0)])
    with pytest.raises(M.MarginsError, match=r"b\.json.*ebad.*sfm.*seed 0.*a\.json"):
        M.load_rows([a, b])


def test_rows_of_different_budgets_are_not_paired(tmp_path):
    a = _write(tmp_path / "a.json", [_row("sfm", "ebad", 0, 26.0, 27.0)], seconds=600.0)
    b = _write(tmp_path / "b.json", [_row("sfm", "bad", 0, 24.0, 23.0)], seconds=300.0)
    with pytest.raises(M.MarginsError, match=r"b\.json: budget .*differs from .*a\.json"):
        M.load_rows([a, b])
    c = _write(tmp_path / "c.json", [_row("sfm", "bad", 0, 24.0, 23.0)], argv=("--refine-iters", "60"))
    with pytest.raises(M.MarginsError, match=r"c\.json: budget"):
        M.load_rows([a, c])


def test_command_line_writes_the_table_and_says_what_is_wrong_in_one_line(tmp_path, capsys):
    a = _write(tmp_path / "a.json", [_row("sfm", "ebad", 0, 26.0, 27.0), _row("sfm", "3dgs", 0, 21.0, 20.0)])
    assert M.main([a]) == 0
    out = capsys.readouterr().out
    assert "commit abc" in out and "| sfm | `3dgs` (the stronger 3dgs) |" in out and "+5.00 (+5.00)" in out
    assert M.main([str(tmp_path / "missing.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.json" in err[0]
    assert M.main([a, "--reference", "bad"]) == 2
    assert "'bad'" in capsys.readouterr().err
