"""Fuzzing the USD reader (hypothesis, derandomized): damaged crate and text layers of a UsdSkel character.

Seeds: the hand-made character of tests/test_io_usd.py as text (``.usda``)
and as crate (``.usdc``). Crate cases flip bytes and truncate (a damaged
crate can ask USD to allocate terabytes: the reader caps the address space,
rigslim.io.usd.stage.memory_budget); text cases replace numbers and tokens
with hostile values. The property is test_fuzz's: every case reads, or
raises rigslim's own error in one line, in a worker under a memory limit and
a per-case timeout.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from tests.framework.io.test_io_usd import make_character
from tests.hostile.test_fuzz import check, examples, worker  # noqa: F401 - the worker fixture


def _seeds() -> tuple[bytes, bytes]:
    from pxr import Usd

    folder = Path(tempfile.mkdtemp(prefix="rigslim-fuzz-usd-"))
    text = make_character(folder / "hero.usda")
    stage = Usd.Stage.Open(str(text))       # held: the layer lives as long as its stage
    stage.GetRootLayer().Export(str(folder / "hero.usdc"))
    return text.read_bytes(), (folder / "hero.usdc").read_bytes()


USDA, USDC = _seeds()
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:e-?\d+)?")
HOSTILE = [b"-1", b"2147483647", b"99999999999", b"nan", b"inf", b"-inf", b"0", b"1e308", b"3.5", b"\"x\""]


@examples(60)
@given(data=st.data())
def test_damaged_crate(worker, data):  # noqa: F811
    blob = bytearray(USDC)
    for _ in range(data.draw(st.integers(1, 24))):
        i = data.draw(st.integers(0, len(blob) - 1))
        blob[i] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        blob = blob[:data.draw(st.integers(0, len(blob)))]
    check(worker, "usd", ".usdc", bytes(blob))


@examples(60)
@given(data=st.data())
def test_hostile_values_in_text(worker, data):  # noqa: F811
    spans = [m.span() for m in NUMBER.finditer(USDA)]
    text = USDA
    for _ in range(data.draw(st.integers(1, 6))):
        a, b = spans[data.draw(st.integers(0, len(spans) - 1))]
        if b <= len(text):
            text = text[:a] + data.draw(st.sampled_from(HOSTILE)) + text[b:]
    check(worker, "usd", ".usda", text)
