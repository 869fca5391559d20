"""How the pairs are cut into block factors (graphcal.calibration.blocks.block_rows)."""

import numpy as np

from graphcal.calibration.blocks import block_rows, m_buckets


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


def test_a_block_ties_a_few_windows_of_m():
    rng = np.random.default_rng(12)
    fibre, window = _draw(2)
    window_m = rng.integers(0, 40, len(fibre))  # revisits: m from any of 40 windows
    blocks = block_rows(fibre, window, window_m, min_rows=300, max_rows=20_000)
    assert np.array_equal(np.sort(np.concatenate(blocks)), np.arange(len(fibre)))
    for rows in blocks:
        assert len(set(window[rows])) == 1
        assert len(set(window_m[rows])) <= 8  # M_WINDOWS
    # without the windows of m, each block of a window spans nearly all 40 of them
    assert np.median([len(set(window_m[rows])) for rows in block_rows(fibre, window, min_rows=300, max_rows=20_000)]) > 30


def test_buckets_of_m_windows_close_at_the_least_rows_or_the_most_windows():
    window_p = np.r_[np.zeros(10, int), np.ones(12, int)]
    window_m = np.r_[[0, 0, 0, 1, 2, 3, 4, 5, 6, 7], np.arange(12)]
    # window 0: m windows 0-3 (6 pairs: at least 6 rows closes), 4-7; window 1: 0-4 (5 windows), 5-9, 10-11
    assert m_buckets(window_p, window_m, min_rows=6, most=5).tolist() == [0] * 6 + [1] * 4 + [2] * 5 + [3] * 5 + [4] * 2
