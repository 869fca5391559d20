"""How the pairs are cut into block factors (graphcal.calibration.blocks.block_rows)."""

import numpy as np

from graphcal.calibration.blocks import block_rows


def _draw(seed: int, n: int = 20_000):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 60, n), rng.integers(0, 4, n)  # fibre of p, window of p's controls


def test_every_pair_once_one_window_a_block_fibres_successive():
    fibre, window = _draw(0)
    blocks = block_rows(fibre, window, min_rows=700, max_rows=900)
    assert np.array_equal(np.sort(np.concatenate(blocks)), np.arange(len(fibre)))
    spans = {}
    for rows in blocks:
        assert len(set(window[rows])) == 1  # a block's controls stay those of one window
        assert len(rows) <= 900
        spans.setdefault(int(window[rows[0]]), []).append((fibre[rows].min(), fibre[rows].max()))
    for window_spans in spans.values():  # a window's blocks hold successive fibres, none shared unless split
        window_spans.sort()
        assert all(hi <= next_lo for (_, hi), (next_lo, _) in zip(window_spans, window_spans[1:]))


def test_fibres_are_merged_up_to_the_least_rows():
    fibre, window = _draw(1)  # about 83 pairs per fibre and window
    merged = block_rows(fibre, window, min_rows=1000, max_rows=20_000)
    per_fibre = block_rows(fibre, window, min_rows=1, max_rows=20_000)
    assert len(per_fibre) == len(np.unique(fibre * 4 + window))
    largest = np.bincount(fibre * 4 + window).max()
    # each block stops at the fibre that brings it to 1000; a window's remainder (under 1000) joins its last block
    assert all(1000 <= len(rows) < 2000 + largest for rows in merged)
    assert len(merged) < len(per_fibre) / 10


def test_a_window_with_fewer_pairs_than_the_least_keeps_one_block():
    window = np.r_[np.zeros(50, int), np.ones(5000, int), np.full(70, 2), np.full(80, 3)]
    fibre = np.r_[np.arange(50) % 7, np.arange(5000) % 9, np.arange(70) % 3, np.arange(80) % 5]
    blocks = block_rows(fibre, window, min_rows=2000, max_rows=20_000)
    # window 1: fibres 0-4 of 556 pairs, 5-8 of 555: fibres 0-3 (2224), 4-7 (2221), and 8 (555) joins the last
    assert sorted(len(rows) for rows in blocks) == [50, 70, 80, 2224, 2776]
    assert np.array_equal(np.sort(np.concatenate(blocks)), np.arange(len(fibre)))
