"""rigslim.plugin.contract: parameter descriptions read from attribute docstrings on demand."""

from __future__ import annotations

import pydantic
from pydantic import Field

from rigslim.plugin.contract import Params, field_descriptions
from rigslim.plugin.host import get_host


class _Base(Params):
    k: int = 4
    """How many weights
    each vertex keeps."""

    lam: float = 0.1


class _Child(_Base):
    lam: float = 0.5
    """The child's own text."""

    tol: float = Field(1e-6, description="from Field")
    """Field's description wins."""

    plain: str = "x"


def test_attribute_docstrings_inherited_overridden_and_field_first():
    assert field_descriptions(_Child) == {"k": "How many weights\neach vertex keeps.", "lam": "The child's own text.",
                                          "tol": "from Field", "plain": ""}
    assert field_descriptions(_Base) == {"k": "How many weights\neach vertex keeps.", "lam": ""}


def test_a_model_without_source_has_no_attribute_docstrings():
    made = pydantic.create_model("Made", __base__=Params, n=(int, 3))
    assert field_descriptions(made) == {"n": ""}


def test_pydantic_no_longer_reads_them_at_class_creation():
    # the point of reading them on demand: no source is parsed when a plugin module is imported
    assert _Child.model_fields["lam"].description is None


def test_schema_and_plugins_table_carry_them():
    info = get_host().info("influence-selection", "best-fit")
    schema = info.params_schema
    described = field_descriptions(info.plugin.Params)
    assert described and all(described.values()), "every best-fit parameter is documented"
    for name, text in described.items():
        assert schema["properties"][name]["description"] == text
