"""The real-character suite (examples/data/gltf/suite/) and the hold-out characters (examples/data/gltf/holdout/):
the indexes tell the truth about the files, and every character is a skinned, animated mesh that rigslim reads,
clip by clip.

What the suite must hold (issue 25, and what issues 22-24 need of it): at least
8 characters, at least 3 with two or more clips (held-out clip tests), several
with at least 30 joints (joint budgets), at least one textured.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.datasets import HOLDOUT, SUITE, index_characters, suite

ROOT = Path(__file__).resolve().parents[2]
CHARACTERS = suite(group="all")
IDS = [c.name for c in CHARACTERS]


def test_the_suite_has_what_the_issues_need():
    assert len(suite()) >= 8
    assert len(suite(multi_clip=True)) >= 3
    assert len(suite(min_joints=30)) >= 4
    assert len(suite(min_joints=30, multi_clip=True)) >= 3
    assert suite(textured=True)
    kinds = " ".join(c.kind for c in suite())
    assert "humanoid" in kinds and "quadruped" in kinds
    assert sum(c.faces >= 600 for c in suite()) >= 7
    assert max(c.faces for c in CHARACTERS) <= 20000
    held = suite(group="holdout")
    assert len(held) >= 4 and not {c.name for c in held} & {c.name for c in suite()}
    assert len(suite(group="holdout", multi_clip=True)) >= 3


def test_an_index_elsewhere_finds_its_files_beside_it(tmp_path):
    """tools/suite/sweep.py's index lies beside its .glb files (older ones named them ``suite/NAME.glb``)."""
    first, second = (json.loads((SUITE / "suite.json").read_text())["characters"][i] for i in (0, 1))
    for e in (first, second):
        (tmp_path / Path(e["file"]).name).write_bytes((SUITE.parent / e["file"]).read_bytes())
    index = tmp_path / "index.json"
    index.write_text(json.dumps({"version": 1, "characters": [first, second | {"file": Path(second["file"]).name}]}))
    chars = index_characters(index)
    assert [c.path for c in chars] == [tmp_path / Path(e["file"]).name for e in (first, second)]
    assert [c.name for c in index_characters(index, [second["name"]])] == [second["name"]]
    with pytest.raises(KeyError, match="no character"):
        index_characters(index, ["nobody"])
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match="bad.json: not a character index"):
        index_characters(tmp_path / "bad.json")


def test_files_stay_small():
    sizes = {c.name: c.path.stat().st_size for c in CHARACTERS}
    assert max(sizes.values()) < 2_000_000, sizes
    assert sum(sizes.values()) < 15_000_000, sizes


def test_every_file_has_provenance():
    readme = (SUITE.parent / "README.md").read_text()
    packages = {**json.loads((SUITE / "suite.json").read_text())["packages"],
                **json.loads((HOLDOUT / "holdout.json").read_text())["packages"]}
    for c in CHARACTERS:
        assert f"`{c.entry['file']}`" in readme, f"{c.name}: no README row"
        for key in ("licence", "author", "source", "sha256"):
            assert c.entry[key], f"{c.name}: no {key}"
        assert c.entry["source"]["package"] in packages


@pytest.mark.parametrize("character", CHARACTERS, ids=IDS)
def test_index_matches_the_file(character):
    data = character.path.read_bytes()
    assert hashlib.sha256(data).hexdigest() == character.entry["sha256"]
    assert len(data) == character.entry["bytes"]
    assert set(character.fit_clips) <= set(character.clip_names)
    assert set(character.holdout_clips) <= set(character.clip_names)
    assert not set(character.fit_clips) & set(character.holdout_clips)
    assert {r["clip"] for r in character.test_renders} <= set(character.clip_names)


@pytest.mark.parametrize("character", CHARACTERS, ids=IDS)
def test_rigslim_reads_every_clip_as_a_moving_skin(character):
    """Each clip reads; each clip to fit, hold out or render poses the mesh: some vertex moves by > 1 % of the
    bind diagonal between the clip's frames (other clips may be held poses, e.g. minetest's ``lay``)."""
    from rigslim.numerics.blend import linear_blend

    used = set(character.fit_clips) | set(character.holdout_clips) | {r["clip"] for r in character.test_renders}
    for clip in character.clip_names:
        s = character.read(clip=clip)
        V, F = s.mesh.V, s.mesh.F
        assert len(F) == character.faces
        assert s.handles.n == character.joints
        W = s.weights.tocsr()
        np.testing.assert_allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0, atol=1e-6)
        assert np.diff(W.indptr).max() <= character.entry["max_influences"]
        T = s.poses.T
        assert len(T) >= 2, f"{clip}: {len(T)} frame(s)"
        diag = np.linalg.norm(V.max(axis=0) - V.min(axis=0))
        frames = np.unique(np.linspace(0, len(T) - 1, 6).round().astype(int))
        posed = np.stack([linear_blend(V, W, T[f]) for f in frames])
        assert np.isfinite(posed).all()
        moved = np.linalg.norm(posed - posed[:1], axis=2).max()
        assert clip not in used or moved > 0.01 * diag, f"{clip}: the mesh moves {moved / diag:.2%} of its diagonal"
        extent = np.linalg.norm(posed.max(axis=1) - posed.min(axis=1), axis=1)
        assert (extent < 3 * diag).all() and (extent > 0.3 * diag).all(), f"{clip}: posed extent {extent / diag}"
