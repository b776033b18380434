"""The safe-output helper every command writes through (issue 11.1)."""

from __future__ import annotations

import os
import stat

import h5py
import numpy as np
import pytest

from imucal_cli.formats.output import (
    OutputError,
    OutputFile,
    check_output,
    safe_output,
    write_output,
)


def leftovers(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_writes_a_new_file_and_leaves_no_temporary(tmp_path):
    out = tmp_path / "a.json"
    assert write_output(out, "hello\n") == out
    assert out.read_text() == "hello\n"
    assert leftovers(tmp_path) == []


def test_existing_file_needs_force(tmp_path):
    out = tmp_path / "a.json"
    out.write_text("old")
    with pytest.raises(OutputError, match=r"already exists \(pass --force to replace it\)"):
        write_output(out, "new")
    assert out.read_text() == "old"
    write_output(out, "new", force=True)
    assert out.read_text() == "new"
    assert leftovers(tmp_path) == []


def test_the_input_is_never_replaced_even_with_force(tmp_path):
    data = tmp_path / "s.h5"
    data.write_bytes(b"recording")
    for target in (data, tmp_path / "." / "s.h5"):
        with pytest.raises(OutputError, match="is the input"):
            write_output(target, "{}", force=True, inputs=[data])
    hard = tmp_path / "alias.h5"
    os.link(data, hard)
    link = tmp_path / "link.h5"
    link.symlink_to(data)
    for target in (hard, link):
        with pytest.raises(OutputError, match="is the input"):
            write_output(target, "{}", force=True, inputs=[data])
    assert data.read_bytes() == b"recording"


def test_a_planted_tmp_link_is_neither_followed_nor_removed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out.json"
    planted = tmp_path / "out.json.tmp"
    planted.symlink_to(victim)
    user_tmp = tmp_path / "other.json.tmp"
    user_tmp.write_text("the user's own file")
    write_output(out, "{}")
    assert victim.read_text() == "precious"
    assert planted.is_symlink() and os.readlink(planted) == str(victim)
    write_output(tmp_path / "other.json", "{}")
    assert user_tmp.read_text() == "the user's own file"
    assert out.read_text() == "{}"


def test_a_link_at_the_target_is_replaced_not_written_through(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out.json"
    out.symlink_to(victim)
    with pytest.raises(OutputError, match="already exists"):
        write_output(out, "{}")
    write_output(out, "{}", force=True)
    assert victim.read_text() == "precious"
    assert not out.is_symlink() and out.read_text() == "{}"
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(OutputError, match="already exists"):
        write_output(dangling, "{}")
    assert not (tmp_path / "nowhere").exists()


def test_refuses_directories_special_files_and_missing_folders(tmp_path):
    with pytest.raises(OutputError, match="is a directory"):
        write_output(tmp_path, "{}", force=True)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="not a regular file"):
        write_output(fifo, "{}", force=True)
    with pytest.raises(OutputError, match="does not exist"):
        write_output(tmp_path / "no" / "such.json", "{}")
    with pytest.raises(OutputError, match="does not exist"):
        check_output(tmp_path / "no" / "such.json")


def test_a_failure_inside_leaves_the_target_as_it_was(tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("old")
    with pytest.raises(RuntimeError):
        with safe_output(out, force=True) as o:
            with o.open("w") as handle:
                handle.write("half")
            raise RuntimeError("solver blew up")
    assert out.read_text() == "old"
    assert leftovers(tmp_path) == []
    with pytest.raises(OutputError, match="cannot write"):
        with safe_output(out, force=True):
            raise OSError(28, "No space left on device")
    assert out.read_text() == "old"
    assert leftovers(tmp_path) == []


def test_a_file_appearing_meanwhile_is_not_clobbered(tmp_path):
    out = tmp_path / "out.json"
    with pytest.raises(OutputError, match="already exists"):
        with safe_output(out) as o:
            with o.open("w") as handle:
                handle.write("mine")
            out.write_text("someone else's")
    assert out.read_text() == "someone else's"
    assert leftovers(tmp_path) == []


def test_h5_output_and_a_replaced_file_keeps_its_mode(tmp_path):
    out = tmp_path / "cal.h5"
    out.write_bytes(b"")
    os.chmod(out, 0o640)
    with safe_output(out, force=True) as o:
        with o.h5() as file:
            file["x"] = np.arange(3.0)
    with h5py.File(out, "r") as file:
        assert file["x"][:].tolist() == [0.0, 1.0, 2.0]
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o640


def test_publish_early_then_keep_writing(tmp_path):
    out = tmp_path / "live.h5"
    o = OutputFile(out)
    file = o.h5(libver="latest")
    file.create_dataset("t", shape=(0,), maxshape=(None,), dtype="f8")
    o.publish()
    assert out.exists() and not o.tmp.exists()
    file["t"].resize((2,))
    file["t"][:] = [1.0, 2.0]
    file.close()
    o.commit()
    with h5py.File(out, "r") as f:
        assert f["t"][:].tolist() == [1.0, 2.0]
    assert leftovers(tmp_path) == []
