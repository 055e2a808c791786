"""Field docstrings read from source: the CLI's help for options that set config fields."""

import pytest

from safe_bc.docs import field_doc


def test_first_sentence_of_a_field_docstring():
    assert field_doc("safe_bc.bc.config", "TrainConfig", "lr") == "Adam learning rate"


def test_long_docstring_stops_at_the_first_sentence():
    text = field_doc("safe_bc.improve.config", "ImproveConfig", "cost_margin")
    assert text.startswith("Tightens the Lagrangian's limit to d_s - cost_margin")
    assert "margin sweep" not in text  # the second sentence is left to the docs


def test_missing_field_or_class_is_a_lookup_error():
    with pytest.raises(LookupError, match="no docstring"):
        field_doc("safe_bc.bc.config", "TrainConfig", "no_such_field")
    with pytest.raises(LookupError, match="not found"):
        field_doc("safe_bc.bc.config", "NoSuchConfig", "lr")
