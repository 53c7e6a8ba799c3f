"""Atomic outputs: the new output replaces the old in one step, a failed write leaves the old one, nothing left over."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from quad_modelling.atomic import atomic_output
from quad_modelling.errors import OutputExistsError

READER = """
import os, sys, time
paths, missing, looks = sys.argv[1:], 0, 0
end = time.monotonic() + float(os.environ["READ_S"])
while time.monotonic() < end:
    looks += 1
    missing += sum(not os.path.exists(p) for p in paths)
print(missing, looks)
"""


def _write_file(path, text):
    with atomic_output(path, force=True) as tmp:
        tmp.write_text(text)


def _write_dir(path, text):
    with atomic_output(path, force=True) as tmp:
        tmp.mkdir()
        (tmp / "results.json").write_text(text)


def test_a_reader_finds_the_old_or_the_new_output_at_every_moment(tmp_path):
    """A second process looks for a replaced file and a replaced directory in a tight loop while each is replaced
    hundreds of times: it never finds either missing (renaming the old one aside first, it did 970 to 4117 times in 2 s)."""
    out_file, out_dir = tmp_path / "model.json", tmp_path / "report"
    _write_file(out_file, "0")
    _write_dir(out_dir, "0")
    reader = subprocess.Popen([sys.executable, "-c", READER, str(out_file), str(out_dir)], stdout=subprocess.PIPE,
                              text=True, env={"READ_S": "2.0"})
    time.sleep(0.3)  # the reader started
    replaced = 0
    while reader.poll() is None:
        _write_file(out_file, str(replaced))
        _write_dir(out_dir, str(replaced))
        replaced += 1
    missing, looks = map(int, reader.communicate()[0].split())
    assert replaced > 50 and looks > 10_000
    assert missing == 0
    assert out_file.read_text() == (out_dir / "results.json").read_text() == str(replaced - 1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json", "report"]  # no staging or old copy left


def test_a_failed_write_leaves_the_old_output_and_nothing_else(tmp_path):
    out = tmp_path / "report"
    _write_dir(out, "old")
    with pytest.raises(RuntimeError), atomic_output(out, force=True) as tmp:
        tmp.mkdir()
        (tmp / "results.json").write_text("half")
        raise RuntimeError("cut")
    assert (out / "results.json").read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["report"]


@pytest.mark.parametrize("kind", ["file", "directory"])
def test_an_earlier_output_that_cannot_be_moved_is_one_line_and_kept(tmp_path, kind):
    """An immutable earlier output (chattr +i; a foreign owner's) made --force end in a PermissionError traceback from
    the final rename: now one OutputDirError, the earlier output whole, no staging or backup left."""
    from quad_modelling.atomic import OutputDirError

    out = tmp_path / ("model.json" if kind == "file" else "report")
    (_write_file if kind == "file" else _write_dir)(out, "old")
    subprocess.run(["chattr", "+i", str(out)], check=True)
    try:
        with pytest.raises(OutputDirError) as err:
            (_write_file if kind == "file" else _write_dir)(out, "new")
    finally:
        subprocess.run(["chattr", "-i", str(out)], check=True)
    assert str(err.value).startswith(f"{out}: cannot put the output in place (Operation not permitted); nothing was written, "
                                     "the earlier output kept")
    assert (out.read_text() if kind == "file" else (out / "results.json").read_text()) == "old"
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_an_existing_output_is_kept_without_force_and_a_file_can_replace_a_directory(tmp_path):
    out = tmp_path / "out"
    _write_dir(out, "old")
    with pytest.raises(OutputExistsError, match="exists; pass --force to overwrite"), atomic_output(out) as tmp:
        tmp.write_text("new")
    assert (out / "results.json").read_text() == "old"
    _write_file(out, "new")
    assert out.is_file() and out.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["out"]


def test_force_replaces_an_earlier_output_directory_not_any_directory(tmp_path):
    """`convert flight -o precious --force` deleted a directory of the user's own files: only a directory holding an
    earlier output's marker (results.json, a bag's metadata.yaml, ...), or an empty one, may be replaced."""
    from quad_modelling.atomic import OUTPUT_MARKERS, OutputExistsError, check_output

    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("important")
    for directory in (False, True):
        with pytest.raises(OutputExistsError, match="is no earlier output of this command"):
            check_output(precious, force=True, directory=directory)
    empty = tmp_path / "empty"
    empty.mkdir()
    check_output(empty, force=True, directory=True)
    for marker in OUTPUT_MARKERS:
        earlier = tmp_path / f"earlier_{marker}"
        earlier.mkdir()
        (earlier / marker).write_text("{}")
        (earlier / "fig_z.png").write_bytes(b"")
        check_output(earlier, force=True, directory=True)


def test_an_earlier_output_is_judged_by_the_verbs_own_files(tmp_path):
    """convert of several inputs writes a directory of bags (no marker at its top: its --force re-run was refused);
    evaluate --force replaced a PX4 recording (a bag's metadata.yaml counted for every verb); run-bag's onboard half
    writes params.yaml and logs only."""
    from quad_modelling.atomic import OutputExistsError, check_output, earlier_output

    bags = tmp_path / "bags"
    for name in ("a", "b"):
        (bags / name).mkdir(parents=True)
        (bags / name / "metadata.yaml").write_text("rosbag2_bagfile_information: {}")
    assert earlier_output(bags, ("metadata.yaml",))
    check_output(bags, force=True, directory=True)
    (bags / "notes.txt").write_text("mine")  # a file beside the bags: not convert's
    assert not earlier_output(bags, ("metadata.yaml",))
    recording = tmp_path / "recording"
    recording.mkdir()
    (recording / "metadata.yaml").write_text("rosbag2_bagfile_information: {}")
    with pytest.raises(OutputExistsError, match="no earlier output of this command .none of results.json."):
        check_output(recording, force=True, directory=True, markers=("results.json",))
    onboard = tmp_path / "onboard"
    (onboard / "logs").mkdir(parents=True)
    (onboard / "params.yaml").write_text("{}")
    check_output(onboard, force=True, directory=True, markers=("results.json", "params.yaml"))


def test_a_dangling_link_or_a_file_name_ending_in_a_slash_is_refused(tmp_path):
    """``-o d.mat`` over a symbolic link to nothing replaced the link without --force (``exists()`` follows it);
    ``train -o m.npz/`` wrote the file m.npz."""
    from quad_modelling.atomic import check_output
    from quad_modelling.atomic import OutputDirError

    (tmp_path / "d.mat").symlink_to(tmp_path / "nowhere.mat")
    with pytest.raises(OutputExistsError, match=rf"d.mat: exists \(a symbolic link to {tmp_path / 'nowhere.mat'}, which does not\)"):
        check_output(tmp_path / "d.mat", False)
    check_output(tmp_path / "d.mat", True)  # --force replaces it
    with pytest.raises(OutputDirError, match=r"-o '.*m.npz/': ends in '/' \(a directory\) but names a .npz file"):
        check_output(f"{tmp_path}/m.npz/", False)
    check_output(f"{tmp_path}/bag/", False, directory=True)  # a directory output may end in one
