"""benchmarks/readme_table.py: the README's speed table is the range of what `vpsim bench --json` wrote."""

from __future__ import annotations

import json


def _report(backward_ms, batch, first_compile=None, load=(1.0, 1.5)):
    return {
        "profile": "quick" if first_compile is None else "full",
        "machine": {"cores": 2, "processor": "cpu", "python": "3.11", "load_average_start_end": list(load)},
        "rows": [
            {
                "tool": "vpsim",
                "method": "backward",
                "driver": None,
                "cycle": "udds",
                "median_ms": backward_ms,
            },
            {
                "tool": "fastsim 3.1.0",
                "method": "conventional walk()",
                "driver": None,
                "cycle": "udds",
                "median_ms": 8.0,
            },
        ],
        "ratios": {"backward_vs_fastsim_udds": 8.0 / backward_ms},
        "batch_backward_runs_per_s": batch,
        "first_compile_s": first_compile,
    }


def test_table_gives_each_figure_as_its_range_over_the_runs(tmp_path, capsys, benchmark_script):
    files = []
    for k, rep in enumerate(
        (_report(0.08, 111000.0), _report(0.10, 47000.0, first_compile=46.2, load=(4, 5)))
    ):
        files.append(tmp_path / f"r{k}.json")
        files[-1].write_text(json.dumps(rep))
    benchmark_script("readme_table").main([str(f) for f in files])
    out = capsys.readouterr().out
    assert "2 runs of `vpsim bench` (full, quick)" in out and "load average 1.0–5.0" in out
    assert "| backward, one UDDS run | 0.08 – 0.10 ms |" in out
    assert "| backward vs FASTSim on UDDS (x faster) | 80x – 100x |" in out
    assert "| batch backward, UDDS | 47,000 – 111,000 runs/s |" in out  # 3 significant digits
    assert "| first compilation of every kernel (empty cache) | 46 s |" in out
    assert "| batch forward, UDDS | not measured |" in out
