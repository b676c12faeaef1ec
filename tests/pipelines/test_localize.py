"""The localization pipeline (probmap.pipelines.localize) on real data: Intel Research Lab, a map
from the corrected log, MCL on the raw odometry and scans."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.pipelines.localize import (
    LocalizeConfig,
    localize_scans,
    match_times,
    trajectory_errors,
)

pytestmark = pytest.mark.realdata

# data/README.md: the corrected log's timestamps are logger time; ipc = logger + this.
INTEL_OFFSET = 976052857.337284


@pytest.fixture(scope="module")
def intel():
    from conftest import _need as need
    from probmap.datasets.carmen import load_scans
    from probmap.pipelines import MappingConfig, map_log

    corrected = need("intel-research-lab/intel-corrected.log.gz")
    raw_path = need("intel-research-lab/intel.clf.bz2")
    grid = map_log(corrected, MappingConfig(resolution=0.05)).grid
    ref = load_scans(corrected)
    raw = load_scans(raw_path, poses="odometry")
    raw_idx, ref_idx = match_times(raw.times, ref.times + INTEL_OFFSET, max_dt=0.02)
    return grid, raw, ref.times + INTEL_OFFSET, ref.laser_poses, raw_idx, ref_idx


def test_intel_tracking_within_gmapping_poses(intel):
    grid, raw, ref_t, ref_p, raw_idx, ref_idx = intel
    # the first 300 corrected scans (about 5 minutes, 4,600 raw scans)
    stop = int(raw_idx[ref_idx < 300].max()) + 1
    start = int(raw_idx[0])
    run = localize_scans(
        grid.spec,
        grid.probability(),
        raw.times,
        raw.ranges,
        raw.angles,
        raw.robot_poses,
        raw.max_range,
        LocalizeConfig(n_particles=1000, initial_pose=tuple(ref_p[ref_idx[0]])),
        start=start,
        stop=stop,
    )
    err, _ = trajectory_errors(run, ref_t, ref_p)
    assert err.size > 200
    assert np.median(err) < 0.10 and np.percentile(err, 95) < 0.30
    # dead reckoning over the same stretch is far off
    odo_err, _ = trajectory_errors(
        type(run)(
            raw.times[start:stop], raw.robot_poses[start:stop], run.spread[:0], run.scan_index[:0]
        ),
        ref_t,
        ref_p,
    )
    assert np.median(odo_err) > 5 * np.median(err)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_intel_global_localization_converges(intel, seed):
    grid, raw, ref_t, ref_p, raw_idx, ref_idx = intel
    # start 50 corrected scans in; 100 updates, then a few more to reach a reference scan
    start = int(raw_idx[50])
    cfg = LocalizeConfig(
        n_particles=20000, global_localization=True, sigma_hit=0.2, z_hit=0.5, z_rand=0.5, seed=seed
    )
    run = localize_scans(
        grid.spec,
        grid.probability(),
        raw.times,
        raw.ranges,
        raw.angles,
        raw.robot_poses,
        raw.max_range,
        cfg,
        start=start,
        max_updates=110,
    )
    err, _ = trajectory_errors(run, ref_t, ref_p)
    # the reference scans met after the 100th update
    late = trajectory_errors(
        type(run)(run.times[100:], run.poses[100:], run.spread[100:], run.scan_index[100:]),
        ref_t,
        ref_p,
    )[0]
    assert late.size >= 1 and late.max() < 0.3


def test_intel_kidnapped_robot_recovers_with_augmented_mcl(intel):
    from probmap.filters.mcl import FreeSpaceSampler, MCLConfig, MonteCarloLocalization
    from probmap.models.likelihood_field import LikelihoodField
    from probmap.models.sampling import OdometryMotionModel

    grid, raw, ref_t, ref_p, raw_idx, ref_idx = intel
    prob = grid.probability()
    lf = LikelihoodField(
        grid.spec, prob, max_range=80.0, sigma_hit=0.2, z_hit=0.5, z_rand=0.5, max_distance=1.0
    )
    free = FreeSpaceSampler(grid.spec, (np.nan_to_num(prob, nan=1.0) < 0.3) & (lf.distance > 0.15))
    mcl = MonteCarloLocalization.from_pose(
        lf,
        OdometryMotionModel(0.3, 0.1, 0.1, 0.3),
        np.random.default_rng(0),
        ref_p[ref_idx[0]],
        np.diag([0.01, 0.01, 0.0025]),
        MCLConfig(n_particles=5000, augmented=True),
        free,
    )
    forced = np.zeros(len(raw.times), dtype=bool)
    forced[raw_idx] = True

    def track(first, stop):
        errs, last = [], first
        for k in range(first + 1, stop):
            d = raw.robot_poses[k] - raw.robot_poses[last]
            turn = abs((d[2] + np.pi) % (2 * np.pi) - np.pi)
            if np.hypot(d[0], d[1]) < 0.1 and turn < 0.1 and not forced[k]:
                continue
            est = mcl.update_scan(
                raw.robot_poses[last], raw.robot_poses[k], raw.ranges[k, ::3], raw.angles[::3]
            )
            last = k
            if forced[k]:
                i = int(np.argmin(np.abs(ref_t - raw.times[k])))
                errs.append(np.hypot(*(est.best_cluster[:2] - ref_p[i, :2])))
        return np.array(errs)

    # track to the 60th matched scan, then the robot is carried 9 m to where the 400th was
    a, b = int(raw_idx[60]), int(raw_idx[400])
    assert np.hypot(*(ref_p[ref_idx[60], :2] - ref_p[ref_idx[400], :2])) > 5.0
    before = track(int(raw_idx[0]), a + 1)
    assert np.median(before) < 0.1
    after = track(b, b + 1000)
    assert after[0] > 5.0  # the kidnap is felt
    assert np.all(after[-10:] < 0.3)  # and recovered from
