"""jaxmocap._files: atomic writes and the natural order of numbered file names."""

import pytest

from jaxmocap._files import atomic_write, natural_key


def test_atomic_write_replaces_the_whole_file_and_leaves_nothing_on_failure(tmp_path):
    path = tmp_path / "result.json"
    atomic_write(path, "old\n")
    atomic_write(path, "new\n")
    assert path.read_text() == "new\n"
    with pytest.raises(TypeError):
        atomic_write(path, 5)  # the write fails half way: the old file stays, no temporary is left
    assert path.read_text() == "new\n"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_natural_key_orders_frame_numbers_as_numbers():
    names = [
        "cam10.json",
        "cam2.json",
        "Cam1.json",
        "cam02_000000000100_keypoints.json",
        "cam02_000000000099_keypoints.json",
    ]
    assert sorted(names, key=natural_key) == [
        "Cam1.json", "cam2.json", "cam02_000000000099_keypoints.json", "cam02_000000000100_keypoints.json", "cam10.json",
    ]  # fmt: skip
