"""Learning while driving (sect. 8): test-then-train on a replayed stream of planted events."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from tests.model.helpers import make_patches, planted
from toolkit.model.online import (
    LearnerState,
    OnlineConfig,
    Replayed,
    Stream,
    reference_of,
    reference_stride,
    replay,
    start,
    step_ends,
)
from toolkit.model.roughness import RoughnessParams, model_pairs, score_events

#: Height alone, no penalty (omega 1: the patch's largest height difference): the drift of
#: the planted smooth events outscores the rough events' step until alpha_3 is learned.
UNINFORMED = (1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0)
INCREMENTS = (0.5, 0.5, 0.005, 0.5, 0.05, 0.5, 0.02, 0.5, 0.02, 0.5, 0.1, 2.0, 0.25)
SPEED_MPS = 10.0
EVENT_M = 1.4


def stream(events: int, seed: int = 3, rough_from: int = 0) -> Stream:
    """Planted events 1.4 m apart at 10 m/s (one rough in five, none before event
    ``rough_from``), each seen 1 s before it began and known 0.5 s after."""
    raw, rough = planted(np.random.default_rng(seed), events, drift_m=(0.05, 0.09))
    if rough_from:
        raw = [raw[e] if not rough[e] or e >= rough_from else raw[e + 1] for e in range(events)]
        rough = rough & (np.arange(events) >= rough_from)
    s = np.arange(events) * EVENT_M
    t = np.round(s / SPEED_MPS * 1e9).astype(np.int64)
    return Stream(t, s, t - 1_000_000_000, t + 500_000_000, rough, make_patches(raw))


CONFIG = OnlineConfig(update_every_m=20.0, buffer_rough=20, buffer_smooth=80)


def fresh() -> LearnerState:
    return start(UNINFORMED, INCREMENTS)


def auc(run: Replayed, s: Stream, rows: np.ndarray) -> float:
    return float(roc_auc_score(s.rough[rows], run.r_combined[rows]))


def test_the_model_learns_as_it_drives() -> None:
    """From height alone, the second half of the drive is ranked far better than the first
    (scored as it came, each event by the model of its time), and better than the start
    would have ranked it."""
    s = stream(600)
    state, run = replay(s, fresh(), CONFIG)
    assert np.isfinite(run.r_combined).all() and (run.version >= 0).all()
    first, second = np.arange(s.events) < 300, np.arange(s.events) >= 300
    unlearned = score_events(model_pairs(s.patches), fresh().params).r_combined
    print(
        f"\nprequential AUC: first half {auc(run, s, first):.3f}, second {auc(run, s, second):.3f}"
    )
    assert auc(run, s, second) > 0.95 > auc(run, s, first)
    # Standings compare across versions: pooled over the second half they rank as well.
    assert roc_auc_score(s.rough[second], run.standing[second]) > 0.95
    assert roc_auc_score(s.rough[second], unlearned[second]) < 0.8
    assert state.params.alpha[2] > 0.01  # the time penalty that separates the classes
    assert state.version > 0 and run.steps_kept.sum() > 0


def test_each_event_is_scored_before_its_label_can_train_the_model() -> None:
    """Changing the labels known after a moment changes no score of an event seen before it,
    and every event is scored by a version made before its own label was known."""
    s = stream(400)
    _, run = replay(s, fresh(), CONFIG)
    moment = s.t_start_ns[200]
    flipped = np.where(s.t_known_ns > moment, ~s.rough, s.rough)
    _, other = replay(dataclasses.replace(s, rough=flipped), fresh(), CONFIG)
    before = s.t_seen_ns <= moment
    np.testing.assert_array_equal(run.r_combined[before], other.r_combined[before])
    assert not np.array_equal(run.r_combined[~before], other.r_combined[~before])
    # The version scoring an event was made at a step that ended before its label was known.
    made_at = np.r_[np.iinfo(np.int64).min, run.step_end_ns]
    first_of_version = {
        int(v): made_at[k] for k, v in reversed(list(enumerate(np.r_[0, run.step_version])))
    }
    assert all(first_of_version[int(v)] < s.t_known_ns[e] for e, v in enumerate(run.version))


def test_a_replay_stopped_and_resumed_gives_the_same_result() -> None:
    s = stream(300)
    whole_state, whole = replay(s, fresh(), CONFIG)
    state, a = replay(s, fresh(), CONFIG, stop_after=7)
    assert state.step == 7
    state, b = replay(s, state, CONFIG)
    got = np.where(np.isnan(a.r_combined), b.r_combined, a.r_combined)
    np.testing.assert_array_equal(got, whole.r_combined)
    assert state.b == whole_state.b and state.mu == whole_state.mu
    np.testing.assert_array_equal(np.r_[a.step_version, b.step_version], whole.step_version)


def test_the_buffer_keeps_the_latest_of_each_class_and_no_more() -> None:
    s = stream(500)
    state, run = replay(s, fresh(), CONFIG)
    assert run.buffer_rough.max() == CONFIG.buffer_rough
    assert run.buffer_smooth.max() == CONFIG.buffer_smooth
    known = s.t_known_ns <= run.step_end_ns[-1]
    rough_known = np.flatnonzero(known & s.rough)[-CONFIG.buffer_rough :]
    smooth_known = np.flatnonzero(known & ~s.rough)[-CONFIG.buffer_smooth :]
    assert sorted(state.buffer.index.tolist()) == sorted([*rough_known, *smooth_known])


def test_without_a_rough_event_the_model_waits_and_calls_nothing_rough() -> None:
    """The first 200 events hold no rough one: until a rough label is known the model stays
    the start (version 0) and, with mu above every score, flags nothing."""
    s = stream(400, rough_from=200)
    _, run = replay(s, fresh(), CONFIG)
    early = s.t_seen_ns < s.t_known_ns[200]
    assert (run.version[early] == 0).all() and not run.predicted[early].any()
    assert run.version.max() > 0


def test_the_model_waits_for_min_rough_labels_and_halving_steps_shrink_per_rotation() -> None:
    """With ``min_rough = 10`` the first version comes after the 10th rough label is known;
    with ``step_rule = "halve"`` the increments halve once per full rotation of B."""
    s = stream(400)
    config = dataclasses.replace(CONFIG, min_rough=10, step_rule="halve", coordinates_per_update=5)
    state, run = replay(s, fresh(), config)
    tenth = np.sort(s.t_known_ns[s.rough])[9]
    assert (run.version[s.t_seen_ns <= tenth] == 0).all() and state.version > 0
    rotations = (5 * state.version) // len(UNINFORMED)
    np.testing.assert_allclose(state.increments, np.array(INCREMENTS) * 0.5**rotations)


def test_a_standing_is_the_share_of_buffered_smooth_events_scored_below() -> None:
    """With ``reference_smooth = 0``: None before a smooth label is known; then in [0, 1]:
    for the events seen in step 11, the share (ties half) of the smooth events in the
    buffer after step 10 that the model after step 10 scores below them."""
    s = stream(300)
    config = dataclasses.replace(CONFIG, reference_smooth=0)
    _, run = replay(s, fresh(), config)
    first_smooth = s.t_known_ns[~s.rough].min()
    assert np.isnan(run.standing[s.t_seen_ns <= first_smooth]).all()
    later = s.t_seen_ns > run.step_end_ns[0]
    assert np.nanmin(run.standing[later]) >= 0.0 and np.nanmax(run.standing[later]) <= 1.0
    after_10, _ = replay(s, fresh(), config, stop_after=10)
    step_11 = (s.t_seen_ns > run.step_end_ns[9]) & (s.t_seen_ns <= run.step_end_ns[10])
    buf = after_10.buffer
    assert step_11.any() and buf.patches is not None
    smooth = buf.patches.take(np.repeat(~buf.rough, 2))
    ref = score_events(model_pairs(smooth), after_10.params).r_combined
    want = [((ref < v).sum() + (ref <= v).sum()) / (2 * ref.size) for v in run.r_combined[step_11]]
    np.testing.assert_allclose(run.standing[step_11], want)


def test_the_reference_is_a_sample_spread_over_every_smooth_label_known() -> None:
    """After every step the reference is every stride-th smooth event known (in the order
    known), the stride the least power of two leaving at most ``reference_smooth``, grown
    step by step to what :func:`reference_of` gives from the whole list; a standing is the
    share of it that its version scores below."""
    s = stream(400)
    config = dataclasses.replace(CONFIG, reference_smooth=16)
    state = fresh()
    strides = set()
    for k in range(step_ends(s, config)[0].size):
        state, run = replay(s, state, config, stop_after=1)
        until = run.step_end_ns[-1]
        known = np.flatnonzero(~s.rough & (s.t_known_ns <= until))
        known = known[np.argsort(s.t_known_ns[known], kind="stable")]
        want = reference_of(known, 16, config.buffer_smooth)
        assert state.reference.index.tolist() == want.tolist(), k
        assert state.reference.known == known.size and want.size <= 16
        strides.add(reference_stride(known.size, 16))
    assert {1, 2, 4, 8} <= strides  # the stride doubled as the labels came
    assert reference_stride(0, 16) == 1 and reference_stride(33, 16) == 4
    after_10, _ = replay(s, fresh(), config, stop_after=10)
    _, whole = replay(s, fresh(), config)
    step_11 = (s.t_seen_ns > whole.step_end_ns[9]) & (s.t_seen_ns <= whole.step_end_ns[10])
    ref_patches = s.patches.take(
        np.stack([2 * after_10.reference.index, 2 * after_10.reference.index + 1], 1).reshape(-1)
    )
    ref = score_events(model_pairs(ref_patches), after_10.params).r_combined
    got = whole.r_combined[step_11]
    want_standing = [((ref < v).sum() + (ref <= v).sum()) / (2 * ref.size) for v in got]
    np.testing.assert_allclose(whole.standing[step_11], want_standing)


def test_averaging_scores_with_the_mean_of_every_version_learned() -> None:
    """With ``average`` the events are scored with B averaged over the versions so far
    (omega rounded), the search itself going on from its latest B."""
    s = stream(200)
    config = dataclasses.replace(CONFIG, average=True)
    state, learned = fresh(), []
    for _ in range(8):
        state, _ = replay(s, state, config, stop_after=1)
        if state.version > len(learned):
            learned.append(state.b)
    assert len(learned) >= 3 and state.scoring
    mean = RoughnessParams.from_vector(np.mean(learned, axis=0).tolist(), 0.0)
    np.testing.assert_allclose(state.params.vector(), mean.vector())
    assert state.params.vector() != state.b


def test_held_out_an_update_is_kept_only_when_it_ranks_the_held_out_events_better() -> None:
    """With half the buffer held out, every version the replay makes ranks the held-out
    half (every other buffered event) at least as well as the version before it did, and the
    model still learns the planted problem."""
    s = stream(600)
    config = dataclasses.replace(CONFIG, validation_share=0.5)
    state, before = fresh(), []
    for _ in range(20):
        prev = state
        state, _ = replay(s, state, config, stop_after=1)
        if state.version > prev.version and state.b != prev.b:
            buf = state.buffer
            held = np.arange(buf.rough.size) % 2 == 1
            assert buf.patches is not None and buf.rough[held].any()
            pairs = model_pairs(buf.patches.take(np.repeat(held, 2)))
            old = score_events(pairs, prev.params).r_combined
            new = score_events(pairs, state.params).r_combined
            before.append(roc_auc_score(buf.rough[held], new) - roc_auc_score(buf.rough[held], old))
    assert before and min(before) > 0.0
    _, run = replay(s, fresh(), config)
    assert auc(run, s, np.arange(s.events) >= 300) > 0.95


def test_steps_end_every_so_many_metres_and_cover_the_drive() -> None:
    s = stream(100)  # 138.6 m
    ends_m, ends_ns = step_ends(s, CONFIG)
    np.testing.assert_allclose(ends_m[:-1], [20, 40, 60, 80, 100, 120])
    assert ends_m[-1] == s.s_start_m[-1]
    assert ends_ns[-1] >= max(s.t_seen_ns.max(), s.t_known_ns.max())
    assert np.all(np.diff(ends_ns) > 0)


def test_a_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError, match="update_every_m"):
        OnlineConfig(update_every_m=0.0)
    with pytest.raises(ValueError, match="buffer"):
        OnlineConfig(buffer_rough=0)
    with pytest.raises(ValueError, match="step_rule"):
        OnlineConfig(step_rule="double")
    with pytest.raises(ValueError, match="validation_share"):
        OnlineConfig(validation_share=0.8)


@pytest.mark.parametrize("smooth", ["buffer", "reference"])
def test_a_refit_is_the_offline_search_on_the_buffer_taken_at_the_next_update(smooth: str) -> None:
    """With refit_every_m, the whole search runs on the buffer (its smooth side, or the
    standings' reference) from the start at each multiple of it; the next update takes its
    model as a new version (no step of its own), the updates going on with the increments
    its search ended on, and the drive is ranked well from there on."""
    s = stream(600)
    config = dataclasses.replace(
        CONFIG, refit_every_m=200.0, refit_iterations=10, refit_smooth=smooth
    )
    first, _ = replay(s, fresh(), config, stop_after=10)  # 10 steps of 20 m: one refit
    assert first.pending, "the refit's model waits for the next update"
    n = len(UNINFORMED)
    nxt, run = replay(s, first, config, stop_after=1)
    assert not nxt.pending and nxt.version == first.version + 1
    assert nxt.b == first.pending[:n] and nxt.mu == first.pending[n]
    assert nxt.increments == first.pending[n + 1 :] != INCREMENTS
    assert run.steps_kept.tolist() == [0]
    state, rest = replay(s, nxt, config)
    second = np.arange(s.events) >= 300
    assert roc_auc_score(s.rough[second], rest.r_combined[second]) > 0.95
    assert (rest.refit_s > 0).sum() == 3  # at 400, 600 and 800 m driven, of 840 m


def test_a_refits_model_waits_for_its_budget_of_driving() -> None:
    """A refit begun at step k with a budget of 5 s of driving (50 m at 10 m/s, steps of
    20 m) is taken by the third update after it, not the next; with coordinates_per_update
    = 0 nothing but refits changes the model, so the versions are the refits'."""
    s = stream(600)
    config = dataclasses.replace(
        CONFIG, refit_every_m=200.0, refit_iterations=10, refit_budget_s=5.0
    )
    first, _ = replay(s, fresh(), config, stop_after=10)
    assert first.pending and first.pending_ready_ns > 0
    waiting, _ = replay(s, first, config, stop_after=2)
    assert waiting.pending == first.pending and waiting.b == first.b
    taken, _ = replay(s, waiting, config, stop_after=1)
    assert not taken.pending and taken.b == first.pending[: len(UNINFORMED)]
    only = dataclasses.replace(config, coordinates_per_update=0)
    state, run = replay(s, fresh(), only)
    assert run.steps_kept.sum() == 0
    # Refits at 200, 400 and 600 m taken; the 800 m one's model, ready at 850 m, is not.
    assert state.version == np.unique(run.step_version).size - 1 == 3 and state.pending
    with pytest.raises(ValueError, match="only refits learn"):
        OnlineConfig(coordinates_per_update=0)
    with pytest.raises(ValueError, match="refit_smooth"):
        OnlineConfig(refit_smooth="everything")
