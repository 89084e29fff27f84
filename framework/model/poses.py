"""Poses: stacks of handle transforms, and the example/validation/test split of frames.

Example poses describe plausible motion and are used for fitting; validation
frames are held out for the solvers' guard; test poses are other frames, never
used in fitting or validation, on which quality is measured.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rigslim.errors import InputError


@dataclass(frozen=True, eq=False)
class Poses:
    """A stack of handle transforms, one per frame.

    Parameters
    ----------
    T : (p, n, 3, 4) float64 array
        ``T[j, i]`` is handle i's affine transform in pose j.
    frames : (p,) int array, optional
        Frame number of each pose (defaults to ``0..p-1``).
    source : str, optional
    """

    T: np.ndarray
    frames: np.ndarray | None = None
    source: str | None = field(default=None, compare=False)

    def __post_init__(self):
        T = np.ascontiguousarray(self.T, dtype=np.float64)
        where = self.source or "poses"
        if T.ndim != 4 or T.shape[2:] != (3, 4):
            raise InputError(f"transform stack has shape {T.shape}, expected (poses, handles, 3, 4)",
                             source=where, field="transforms", fix="give one 3x4 transform per handle and pose")
        if not np.isfinite(T).all():
            raise InputError("transforms contain NaN or inf", source=where, field="transforms",
                             fix="repair or re-export the animation")
        frames = np.arange(len(T)) if self.frames is None else np.asarray(self.frames, dtype=np.int64)
        object.__setattr__(self, "T", T)
        object.__setattr__(self, "frames", frames)

    def __len__(self) -> int:
        return len(self.T)

    @property
    def n_handles(self) -> int:
        return self.T.shape[1]

    def select(self, frames) -> Poses:
        """The poses of the given frame numbers, in that order."""
        assert self.frames is not None  # __post_init__ set it (0..p-1 when not given)
        index = {int(f): j for j, f in enumerate(self.frames)}
        rows = [index[int(f)] for f in frames]
        return Poses(self.T[rows], np.asarray(frames, dtype=np.int64), source=self.source)


def parse_frames(spec, count: int, *, source: str | None = None, field_name: str = "poses") -> list[int]:
    """Frame numbers from a spec.

    Parameters
    ----------
    spec : str, int or list
        ``"start:stop:step"`` (Python slice semantics, as in ``"0:457:45"``),
        ``"a,b,c"``, a single int, or a list of ints/specs.
    count : int
        Number of frames available; every frame must be in ``0..count-1``.

    Returns
    -------
    list of int
        Sorted unique frame numbers.
    """
    def bad(msg, fix):
        return InputError(msg, source=source, field=field_name, fix=fix)

    if isinstance(spec, bool) or spec is None:
        raise bad(f"frame spec {spec!r} is not understood", 'write "start:stop:step", "a,b,c" or a list')
    if isinstance(spec, (list, tuple)):
        out = []
        for s in spec:
            out += parse_frames(s, count, source=source, field_name=field_name)
        frames = out
    elif isinstance(spec, (int, np.integer)):
        frames = [int(spec)]
    elif isinstance(spec, str):
        s = spec.strip()
        if ":" in s:
            parts = s.split(":")
            if len(parts) > 3:
                raise bad(f"frame spec {spec!r} has too many ':'", 'write "start:stop:step"')
            try:
                nums = [int(p) if p.strip() else None for p in parts]
            except ValueError:
                raise bad(f"frame spec {spec!r} is not start:stop:step", 'write e.g. "0:457:45"') from None
            if len(nums) == 3 and nums[2] is not None and nums[2] <= 0:
                raise bad(f"frame spec {spec!r} has a step <= 0", "use a positive step")
            start, stop = nums[0], nums[1]
            if (start is not None and start >= count) or (stop is not None and stop > count):
                raise bad(f"frame spec {spec!r} runs past the last frame ({count - 1})",
                          f"keep frames within 0..{count - 1}")
            frames = list(range(count))[slice(*nums)]
        else:
            try:
                frames = [int(p) for p in s.split(",") if p.strip()]
            except ValueError:
                raise bad(f"frame spec {spec!r} is not understood", 'write "start:stop:step" or "a,b,c"') from None
    else:
        raise bad(f"frame spec {spec!r} is not understood", 'write "start:stop:step", "a,b,c" or a list')
    for f in frames:
        if f < 0 or f >= count:
            raise bad(f"frame {f} is out of range 0..{count - 1}", f"keep frames within 0..{count - 1}")
    if not frames:
        raise bad(f"frame spec {spec!r} selects no frame", "choose at least one frame")
    return sorted(set(frames))


#: Example frames per clip at least (a short clip's motion is seen, and its validation frames spread over it).
MIN_CLIP_EXAMPLES = 3


def sample_clip_frames(lengths, count: int) -> list[tuple[list[int], list[int], list[int]]]:
    """Per clip of ``lengths`` frames, its (examples, validation, test) frames, disjoint.

    ``count`` example frames in all, shared out in proportion to the lengths, at least
    :data:`MIN_CLIP_EXAMPLES` per clip (where it has the frames). A clip of n frames with e examples
    gets the step ``s = max(3, ceil(n / e))``: examples at frames ``0, s, 2s, ...``; the other frames,
    in time order, are dealt alternately to validation and test (``f_1 -> validation, f_2 -> test,
    f_3 -> validation, ...``), so that every test frame lies between validation or example frames and
    the two sets are samples of the same motion, equally far from the examples: an error bound that
    holds on the validation frames (the solvers' guard) holds on the test frames up to the sampling
    noise. A clip of 2 frames: example 0, test 1.

    (Validation frames were the first half of each gap and test frames the second: on a 16-frame clip
    that is 9 validation frames, 3 of them in the last gap, against 4 test frames.)
    """
    lengths = [int(n) for n in lengths]
    total = max(sum(lengths), 1)
    out: list[tuple[list[int], list[int], list[int]]] = []
    for n in lengths:
        if n < 1:
            out.append(([], [], []))
            continue
        e = max(MIN_CLIP_EXAMPLES, int(round(count * n / total)))
        s = max(3, -(-n // e))
        ex = list(range(0, n, s))
        rest = [f for f in range(n) if f % s]
        val, te = rest[0::2], rest[1::2]
        if n == 2:
            val, te = [], [1]
        out.append((ex, val, te))
    return out


def spread_frames(n: int, most: int) -> list[int]:
    """At most ``most`` of ``n`` frames, evenly spread, first and last included (all when ``most`` is 0 or at
    least ``n``): the frames a measurement that cannot afford every test frame takes."""
    if most <= 0 or n <= most:
        return list(range(n))
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, most)})


def farthest_poses(X: np.ndarray, count: int) -> list[int]:
    """Rows of ``X`` (one descriptor per pose) chosen by farthest-point sampling (Gonzalez 1985).

    Start at row 0; then, ``count - 1`` times, the row whose distance to the nearest row chosen so far,
    ``d(x) = min_c ||x - X_c||``, is largest (the first such row not yet chosen on ties). The chosen rows cover the
    descriptors within a factor 2 of the best covering radius with ``count`` centres. Returns the chosen
    rows, sorted (all rows when ``count >= len(X)``).
    """
    X = np.asarray(X, np.float64).reshape(len(X), -1)
    if count >= len(X):
        return list(range(len(X)))
    chosen = [0]
    d = np.linalg.norm(X - X[0], axis=1)
    d[0] = -np.inf
    for _ in range(count - 1):
        c = int(np.argmax(d))          # never a chosen row, even among repeats (all at distance 0)
        chosen.append(c)
        d = np.minimum(d, np.linalg.norm(X - X[c], axis=1))
        d[chosen] = -np.inf
    return sorted(chosen)


def thin_examples(sampled: list[tuple[list[int], list[int], list[int]]], descriptors, most: int
                  ) -> list[tuple[list[int], list[int], list[int]]]:
    """:func:`sample_clip_frames`'s split with at most ``most`` example frames in all: where the clips'
    shares add up to more (many clips, each with its :data:`MIN_CLIP_EXAMPLES`), the examples kept are the
    :func:`farthest_poses` of their ``descriptors`` (``descriptors(clip, frames) -> (len(frames), d)``: the
    poses compared, e.g. posed positions of some vertices), so that different motions keep their examples
    and near repeats (a jump to the left and to the right) share theirs. An example frame not kept becomes a
    validation frame of its clip; the test frames are unchanged."""
    total = sum(len(ex) for ex, _, _ in sampled)
    if total <= most:
        return sampled
    owners = [(c, f) for c, (ex, _, _) in enumerate(sampled) for f in ex]
    X = np.concatenate([descriptors(c, ex) for c, (ex, _, _) in enumerate(sampled) if ex], axis=0)
    keep = {owners[i] for i in farthest_poses(X, most)}
    out = []
    for c, (ex, val, te) in enumerate(sampled):
        out.append(([f for f in ex if (c, f) in keep], sorted(val + [f for f in ex if (c, f) not in keep]), te))
    return out


@dataclass(frozen=True)
class FrameSplit:
    """Example frames (for fitting) and test frames (for measuring), disjoint.

    ``dropped`` lists test frames that were also example frames and so were
    removed from the test set. ``clips`` is set when the frames come from named
    clips (fitting on one clip, testing on another).
    """

    examples: list[int]
    test: list[int]
    dropped: list[int]
    #: Two-clip splits (:mod:`rigslim.runtime.clips`): ``{"examples": {"clip", "frames"}, "test": {...}}`` with
    #: each clip's own frame numbers; the lists above number the stacked poses. Splits over several clips
    #: (``clips:``) hold a list of ``{"clip", "frames"}`` per side, ``validation`` included.
    clips: dict | None = None
    #: Held-out frames for the solvers' guard (neither example nor test frames; empty: no guard).
    validation: list[int] = field(default_factory=list)
    #: The stacked clips: ``[{"clip": name, "start": first stack frame, "frames": count}, ...]`` (None: one clip).
    segments: list[dict] | None = None

    def clip_groups(self, frames) -> list[list[int]]:
        """``frames`` grouped by the clip of :attr:`segments` they fall in (one group without segments)."""
        frames = list(frames)
        if not self.segments:
            return [frames] if frames else []
        groups = [[f for f in frames if s["start"] <= f < s["start"] + s["frames"]] for s in self.segments]
        return [g for g in groups if g]

    @staticmethod
    def from_specs(examples, test, count: int, *, source: str | None = None) -> FrameSplit:
        ex = parse_frames(examples, count, source=source, field_name="poses.examples")
        te = parse_frames(test, count, source=source, field_name="poses.test")
        dropped = sorted(set(ex) & set(te))
        te = [f for f in te if f not in set(ex)]
        if not te:
            raise InputError("every test frame is also an example frame", source=source,
                             field="poses.test", fix="choose test frames that are not example frames")
        return FrameSplit(ex, te, dropped)
