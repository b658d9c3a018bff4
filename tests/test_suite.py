"""Task suites: the file format, the shipped suites, the generator's order and determinism."""
from __future__ import annotations

import gzip
import json
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from fetchbench_ms.tasks import suite_build
from fetchbench_ms.tasks.suite import TaskSuite, load_suite, shipped_suites
from fetchbench_ms.tasks.suite_build import PAPER_TABLE, SuiteRecipe, plan_scenes, stratified_order
from fetchbench_ms.tasks.suite_cli import category_mix_misses, format_stats, suite_stats


@pytest.fixture(scope="module")
def smoke():
    return load_suite("smoke")


@pytest.fixture(scope="module")
def test_suite():
    return load_suite("test")


# ----------------------------------------------------------------------------- file format
def test_round_trip_is_compact_and_byte_stable(tmp_path, smoke):
    path = tmp_path / "s.json.gz"
    smoke.save(path)
    again = load_suite(path)
    assert again.ids() == smoke.ids() and again.tasks == smoke.tasks and again.info == smoke.info
    again.save(tmp_path / "t.json.gz")
    assert (tmp_path / "t.json.gz").read_bytes() == path.read_bytes()
    body = json.loads(gzip.decompress(path.read_bytes()))
    # Each scene and arrangement once: tasks of one arrangement share it.
    assert len(body["arrangements"]) <= len(body["tasks"])
    assert len(body["scenes"]) == len({(t.scene_type, t.scene_seed) for t in smoke.tasks.values()})


def test_two_targets_of_one_arrangement_share_it(tmp_path, smoke):
    task = smoke.get(smoke.ids()[0])
    other = (task.target_index + 1) % len(task.objects)
    suite = TaskSuite("pair", {"pair/0": task, "pair/1": replace(task, target_index=other)})
    suite.save(tmp_path / "p.json")
    body = json.loads((tmp_path / "p.json").read_text())
    assert len(body["arrangements"]) == 1 and len(body["scenes"]) == 1
    assert load_suite(tmp_path / "p.json").get("pair/1").target_index == other


def test_tampered_file_is_rejected(tmp_path, smoke):
    path = tmp_path / "s.json"
    smoke.save(path)
    body = json.loads(path.read_text())
    body["arrangements"][0]["objects"][0]["position"][2] += 0.01
    path.write_text(json.dumps(body))
    with pytest.raises(ValueError, match="corrupt: its content does not match its sha256"):
        load_suite(path)
    (tmp_path / "junk.json.gz").write_bytes(b"\x1f\x8b not gzip")
    with pytest.raises(ValueError, match="corrupt"):
        load_suite(tmp_path / "junk.json.gz")


def test_old_version_is_refused(tmp_path, smoke):
    path = tmp_path / "old.json"
    body = smoke.to_body()
    body["version"] = "1"
    from fetchbench_ms.utils.io import canonical_json, sha256_bytes

    body["sha256"] = sha256_bytes(canonical_json(body).encode())
    path.write_text(json.dumps(body))
    with pytest.raises(ValueError, match="version '1' task suite.*regenerate"):
        load_suite(path)


def test_unknown_suite_and_task_id_name_the_valid_ones(smoke):
    with pytest.raises(ValueError, match=r"unknown task suite 'tset'; valid: .*smoke.*test"):
        load_suite("tset")
    with pytest.raises(FileNotFoundError):
        load_suite("missing/suite.json.gz")
    with pytest.raises(KeyError, match=r"unknown task id 'smoke/9999' in suite 'smoke'; valid: smoke/0000"):
        smoke.get("smoke/9999")


def test_shipped_suites_listed():
    assert {"smoke", "test", "val"} <= set(shipped_suites())


# ----------------------------------------------------------------------------- order and plan
def test_stratified_order_prefixes_are_proportional():
    rng = np.random.default_rng(0)
    keys = list(rng.choice(["a", "b", "c", "d"], p=[0.5, 0.3, 0.15, 0.05], size=400))
    order = stratified_order(keys)
    assert sorted(order) == list(range(400))
    sizes = Counter(keys)
    for n in (10, 40, 100, 250):
        counts = Counter(keys[i] for i in order[:n])
        for key, size in sizes.items():
            assert abs(counts[key] - n * size / 400) <= 1.5, (n, key)
    # Within a stratum the given order is kept.
    a_positions = [i for i in order if keys[i] == "a"]
    assert a_positions == sorted(a_positions)


def test_test_plan_has_the_papers_scene_counts_and_category_mix():
    plans = plan_scenes(suite_build.recipe("test"))
    assert Counter(p.scene_type for p in plans) == {t: n for t, (n, _) in PAPER_TABLE.items()}
    assert all(sum(p.quota.values()) == 60 for p in plans)
    # Without the plan's shifts, the quotas are the paper's split, type by type.
    paper_plans = plan_scenes(suite_build.recipe("test"), shifts={})
    for scene_type, (_, by_label) in PAPER_TABLE.items():
        totals = Counter()
        for p in paper_plans:
            if p.scene_type == scene_type:
                totals.update(p.quota)
        assert {c: totals[c] for c in by_label} == by_label, scene_type
    # The shifts move tasks between categories inside a type (its task count stays), and only
    # where the type has both categories.
    for scene_type, shift in suite_build.PLAN_SHIFTS.items():
        assert sum(shift.values()) == 0
        assert all(PAPER_TABLE[scene_type][1][c] + n >= 0 for c, n in shift.items())
    shifted = {p.index: p.quota for p in plans}
    assert [p.quota for p in paper_plans if p.scene_type not in suite_build.PLAN_SHIFTS] == \
        [shifted[p.index] for p in paper_plans if p.scene_type not in suite_build.PLAN_SHIFTS]
    # The first 13 scenes made cover every type (a partial build is still a fair sample).
    assert {p.scene_type for p in plans[:13]} == set(PAPER_TABLE)
    assert len({p.scene_seed for p in plans}) == len(plans)


def test_bad_recipe_is_refused():
    with pytest.raises(ValueError, match="unknown suite recipe 'tests'; valid: test, train, val"):
        suite_build.recipe("tests")
    with pytest.raises(ValueError, match="valid: train, test"):
        SuiteRecipe(object_split="all")


# ----------------------------------------------------------------------------- shipped suites
def _strata(suite):
    return [(t.scene_type, t.target_label) for t in suite.tasks.values()]


def test_shipped_test_suite_prefix_is_stratified(test_suite):
    keys = _strata(test_suite)
    sizes, n_all = Counter(keys), len(keys)
    strata = len(sizes)
    for fraction in (0.1, 0.25, 0.5):
        n = int(n_all * fraction)
        counts = Counter(keys[:n])
        for key, size in sizes.items():
            # Every stratum within one task of its share at its position, plus rounding
            # spread over the strata.
            assert abs(counts[key] - n * size / n_all) <= 1 + strata * size / n_all + 1e-9, (fraction, key)


def test_shipped_test_suite_meets_its_plan_or_says_it_is_partial(test_suite):
    info = test_suite.info
    plans = plan_scenes(suite_build.recipe("test"))
    assert info["planned_scenes"] == 100 and info["planned_tasks"] == 6000
    by_index = {p.index: p for p in plans}
    made = [by_index[i] for i in info["complete_scene_indices"]]
    assert info["complete_scenes"] == len(made) and info["complete"] == (len(made) == 100)
    # Every task comes from a finished scene of the plan, from test-split objects.
    scene_seeds = {(p.scene_type, p.scene_seed) for p in made}
    assert {(t.scene_type, t.scene_seed) for t in test_suite.tasks.values()} <= scene_seeds
    from fetchbench_ms.objects.loading import object_ids

    test_ids = set(object_ids("test"))
    assert all(o.object_id in test_ids for t in test_suite.tasks.values() for o in t.objects)
    # Each finished scene has its quota, except the shortfall it records.
    per_scene = Counter(t.scene_seed for t in test_suite.tasks.values())
    for p in made:
        short = sum(info["shortfall"].get(str(p.index), {}).values())
        assert per_scene[p.scene_seed] >= 60 - short
    if info["complete"]:
        stats = suite_stats(test_suite)
        assert {t: r["scenes"] for t, r in stats["rows"].items()} == {t: n for t, (n, _) in PAPER_TABLE.items()}
        paper = {"on_table": 1526, "on_shelf": 2724, "in_drawer": 859, "in_basket": 891}
        assert stats["planned_by_category"] == paper
        off = [label for label, n in paper.items() if abs(stats["total"][label] - n) > 0.1 * n]
        # The paper's mix, or the table says plainly which categories miss it.
        assert category_mix_misses(stats) == off
        text = format_stats(stats)
        assert ("NOT MET" in text) == bool(off) and "category mix vs the paper's" in text
    else:
        assert "PARTIAL" in format_stats(suite_stats(test_suite))


@pytest.mark.parametrize("name", ["train", "val"])
def test_learning_suites_hold_no_test_split_object(name):
    """Every object of every arrangement (targets and clutter) of the suites that methods
    train and tune on is a train-split object; none is of the test split."""
    from fetchbench_ms.objects.loading import object_ids

    suite = load_suite(name)
    used = {o.object_id for t in suite.tasks.values() for o in t.objects}
    assert len(suite) > 0 and used <= set(object_ids("train"))
    assert not used & set(object_ids("test"))


def test_smoke_covers_every_category_and_most_types(smoke, test_suite):
    assert 15 <= len(smoke) <= 25
    assert {t.target_label for t in smoke.tasks.values()} == {t.target_label for t in test_suite.tasks.values()}
    types = {t.scene_type for t in smoke.tasks.values()}
    assert len(types) >= min(7, len({t.scene_type for t in test_suite.tasks.values()}))
    for smoke_id, test_id in zip(smoke.ids(), smoke.info["source_ids"]):
        assert smoke.get(smoke_id) == test_suite.get(test_id)


def test_stats_cli(capsys):
    from fetchbench_ms.cli import main

    assert main(["suite", "stats", "--suite", "smoke", "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["total"]["tasks"] == sum(r["tasks"] for r in stats["rows"].values())
    assert stats["total"]["tasks"] == sum(stats["total"][c] for c in ("on_table", "on_shelf", "in_drawer", "in_basket"))
    assert main(["suite", "stats", "--suite", "test", "--filters"]) == 0
    out = capsys.readouterr().out
    assert "# Scenes" in out and "In-Basket" in out and "Total" in out and "unreachable" in out
    assert main(["suite", "stats", "--suite", "nope"]) == 2
    assert "valid:" in capsys.readouterr().err


@pytest.mark.slow
def test_generated_suite_is_identical_whatever_the_worker_count(tmp_path):
    r = SuiteRecipe("tiny", "test", seed=7, scale=0.1, tasks_per_scene=2, max_arrangements=3)
    paths = []
    for workers in (1, 2):
        work = tmp_path / f"w{workers}"
        suite_build.build_scenes(r, work, workers=workers, limit=2, log=lambda *_: None)
        suite = suite_build.assemble_suite(r, work)
        paths.append(tmp_path / f"tiny{workers}.json.gz")
        suite.save(paths[-1])
        assert suite.info["complete_scenes"] == 2 and not suite.info["complete"]
    assert paths[0].read_bytes() == paths[1].read_bytes()
    # The per-scene results (every filter verdict counted) agree too, time aside.
    for name in ("scene_000.json", "scene_001.json"):
        a, b = (json.loads((tmp_path / f"w{w}" / name).read_text()) for w in (1, 2))
        assert a.pop("seconds") > 0 and b.pop("seconds") > 0
        assert a == b and a["candidates"] > 0
    # Re-running skips finished scenes (resumable): nothing is remade.
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "w1").iterdir()}
    suite_build.build_scenes(r, tmp_path / "w1", workers=1, limit=2, log=lambda *_: None)
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "w1").iterdir()} == before


def test_a_killed_scene_build_continues_from_its_progress_to_the_same_result(tmp_path):
    """A scene's state is saved after each arrangement; a build killed in the middle of a
    scene continues there and ends with the result an uninterrupted build gives."""
    from fetchbench_ms.tasks.filters import FilterEnv

    r = SuiteRecipe("tiny", "test", seed=7, scale=0.1, tasks_per_scene=60, max_arrangements=2)
    scene = suite_build.plan_scenes(r)[0]

    class Killed(Exception):
        pass

    class KilledOnSecondCheck:
        def __init__(self, env):
            self.env, self.calls = env, 0

        def check(self, *args, **kwargs):
            self.calls += 1
            if self.calls == 2:
                raise Killed
            return self.env.check(*args, **kwargs)

    env = FilterEnv(num_objects=r.num_objects)
    try:
        whole = suite_build.build_scene(r, scene, env, progress_path=tmp_path / "whole.progress.json")
        progress = tmp_path / "cut.progress.json"
        with pytest.raises(Killed):
            suite_build.build_scene(r, scene, KilledOnSecondCheck(env), progress_path=progress)
        assert json.loads(progress.read_text())["state"]["next"] == 1
        resumed = suite_build.build_scene(r, scene, env, progress_path=progress)
    finally:
        env.close()
    assert whole.pop("seconds") > 0 and resumed.pop("seconds") > 0
    assert resumed == whole and whole["candidates"] > 0
    # Progress of another recipe is not taken for this one's.
    other = SuiteRecipe("tiny", "test", seed=8, scale=0.1, tasks_per_scene=60, max_arrangements=2)
    state = json.loads(progress.read_text())
    assert state["key"] != suite_build._scene_key(other, suite_build.plan_scenes(other)[0])


def test_a_larger_fill_budget_continues_only_short_scenes_to_a_fresh_builds_result(tmp_path):
    """A scene short of its task count after ``max_arrangements`` goes on in the fill phase;
    raising ``fill_arrangements`` continues such a scene from its result (no progress file
    needed) and ends where a fresh build with that budget ends."""
    from dataclasses import replace

    from fetchbench_ms.tasks.filters import FilterEnv

    with pytest.raises(ValueError, match="fill_arrangements"):
        SuiteRecipe("tiny", max_arrangements=3, fill_arrangements=2)
    short = SuiteRecipe("tiny", "test", seed=7, scale=0.1, tasks_per_scene=60, max_arrangements=1)
    filled = replace(short, fill_arrangements=2)
    scene = suite_build.plan_scenes(short)[0]
    logs = []
    try:
        suite_build.build_scenes(short, tmp_path, workers=1, limit=1, log=logs.append)
        path = suite_build._scene_path(tmp_path, scene)
        first = json.loads(path.read_text())
        assert first["tried"] == 1 and len(first["tasks"]) < 60  # 60 tasks never fit one arrangement
        assert suite_build._scene_status(short, scene, tmp_path) == "done"
        assert suite_build._scene_status(filled, scene, tmp_path) == "short"
        suite_build.build_scenes(filled, tmp_path, workers=1, limit=1, log=logs.append)
        continued = json.loads(path.read_text())
        env = FilterEnv(num_objects=filled.num_objects)
        try:
            fresh = suite_build.build_scene(filled, scene, env)
        finally:
            env.close()
    finally:
        if suite_build._WORKER_ENV is not None:
            suite_build._WORKER_ENV.close()
            suite_build._WORKER_ENV = None
    assert any("continuing short scenes [0] up to 2 arrangements" in line for line in logs)
    assert continued.pop("seconds") > first["seconds"] and fresh.pop("seconds") > 0
    assert continued == fresh and continued["tried"] == 2
    # The fill phase IK-checks every stable, visible object: more candidates, no "unchecked".
    assert continued["candidates"] > first["candidates"]
    assert continued["rejected"].get("unchecked", 0) == first["rejected"].get("unchecked", 0)
    # A result made with a larger budget is stale for a smaller one (it would differ).
    assert "more arrangements" in suite_build._stale_reason(short, scene, continued)


def test_merging_two_copies_of_a_work_dir_keeps_each_scene_furthest_along(tmp_path):
    """Two machines building one suite (one with ``--reverse``) each leave finished scenes
    and progress files; merging keeps a finished scene over any progress, and the progress
    with more arrangements tried, and never goes back."""
    def progress(next_arrangement):
        return json.dumps({"key": {}, "state": {"next": next_arrangement}})

    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    (here / "scene_000.json").write_text('{"done": "here"}')
    (there / "scene_000.json").write_text('{"done": "there"}')
    (here / "scene_001.progress.json").write_text(progress(5))
    (there / "scene_001.json").write_text('{"done": "there"}')
    (here / "scene_002.progress.json").write_text(progress(9))
    (there / "scene_002.progress.json").write_text(progress(4))
    (here / "scene_003.progress.json").write_text(progress(2))
    (there / "scene_003.progress.json").write_text(progress(7))
    (there / "scene_004.progress.json").write_text(progress(1))
    (here / "scene_005.json").write_text('{"done": "here"}')
    (there / "scene_005.progress.json").write_text(progress(50))
    taken = suite_build.merge_work_dirs(there, here)
    assert taken == ["scene_001.json", "scene_003.progress.json", "scene_004.progress.json"]
    assert json.loads((here / "scene_000.json").read_text()) == {"done": "here"}
    assert (here / "scene_001.json").exists() and not (here / "scene_001.progress.json").exists()
    assert json.loads((here / "scene_002.progress.json").read_text())["state"]["next"] == 9
    assert json.loads((here / "scene_003.progress.json").read_text())["state"]["next"] == 7
    assert not (here / "scene_005.progress.json").exists()
    assert suite_build.merge_work_dirs(there, here) == []


def test_shipped_suites_are_found_in_an_installed_wheel(tmp_path, monkeypatch):
    """In a wheel the assets are fetchbench_ms/_assets; a top-level "assets" folder another
    distribution put in site-packages is not mistaken for a checkout's."""
    from fetchbench_ms.tasks.suite import shipped_suite_file, shipped_suites
    from fetchbench_ms.utils import paths

    checkout_assets = paths.assets_root()
    assert shipped_suite_file("test").parent == checkout_assets / "suites"
    site = tmp_path / "site-packages"
    (site / "assets" / "suites").mkdir(parents=True)  # the other distribution's folder
    (site / "fetchbench_ms").mkdir()
    (site / "fetchbench_ms" / "_assets").symlink_to(checkout_assets, target_is_directory=True)
    monkeypatch.setattr(paths, "_PACKAGE", site / "fetchbench_ms")
    assert shipped_suite_file("test") is not None
    assert shipped_suite_file("test").parent == site / "fetchbench_ms" / "_assets" / "suites"
    assert {"test", "val"} <= set(shipped_suites())
