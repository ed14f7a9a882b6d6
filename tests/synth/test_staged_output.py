"""Staged writes: a folder filled by another writer meanwhile is kept, and the loser says so."""

from __future__ import annotations

import pytest

from components.synth.writer import OutputTakenError, staged_output
from tridehaze_plugin.errors import UserError


def test_a_folder_filled_while_writing_is_kept_and_the_second_writer_stops(tmp_path):
    out = tmp_path / "scene"
    with pytest.raises(OutputTakenError, match="filled by someone else") as err:
        with staged_output(out, overwrite=False, tool="td-synth") as tmp:
            (tmp / "mine.txt").write_text("second")
            out.mkdir()  # the first writer's rename lands now
            (out / "theirs.txt").write_text("first")
    assert isinstance(err.value, UserError) and str(out) in str(err.value)
    assert sorted(p.name for p in out.iterdir()) == ["theirs.txt"]  # untouched
    assert [p.name for p in tmp_path.iterdir()] == ["scene"]  # the staged copy is gone


def test_an_unfilled_folder_is_replaced_by_the_staged_copy(tmp_path):
    out = tmp_path / "scene"
    with staged_output(out, overwrite=False, tool="td-synth") as tmp:
        (tmp / "mine.txt").write_text("only")
    assert (out / "mine.txt").read_text() == "only"
    assert [p.name for p in tmp_path.iterdir()] == ["scene"]
