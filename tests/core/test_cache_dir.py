"""A cache directory that cannot be used is reported by what is wrong with it
(not a directory, a file system that holds no files), naming ``$MCRT_CACHE_DIR``
when the path came from it, before any work; never as a lack of free space."""

from __future__ import annotations

import os

import pytest

from mcrt.core.atomic import check_free_space
from mcrt.errors import McrtError
from tests.conftest import TINY_SCENE, run_cli


def _reference(tmp_path, capsys) -> tuple[int, str]:
    scene = tmp_path / "tiny.xml"
    scene.write_text(TINY_SCENE)
    out = tmp_path / "out" / "r.exr"
    code, _, err = run_cli(capsys, "-q", "reference", str(scene), "--spp", "4", "-o", str(out))
    assert not out.exists(), err  # refused before work
    return code, err


def test_cache_dir_under_a_file_is_named_as_such(tmp_path, capsys, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("in the way")
    monkeypatch.setenv("MCRT_CACHE_DIR", str(blocker / "cache"))
    code, err = _reference(tmp_path, capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert f"{blocker} is not a directory" in lines[0], err
    assert f"$MCRT_CACHE_DIR={blocker / 'cache'}" in lines[0], err
    assert "free space" not in err


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_cache_dir_on_a_pseudo_file_system_is_not_a_lack_of_space(tmp_path, capsys,
                                                                  monkeypatch):
    monkeypatch.setenv("MCRT_CACHE_DIR", "/proc/mcrt-cache")
    code, err = _reference(tmp_path, capsys)
    assert code == 2 and "free space" not in err, err
    assert "cannot create /proc/mcrt-cache/reference" in err
    assert "$MCRT_CACHE_DIR=/proc/mcrt-cache" in err


def test_output_directory_message_does_not_blame_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MCRT_CACHE_DIR", str(tmp_path / "cache"))
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with pytest.raises(McrtError) as error:
        check_free_space(blocker / "out", 1, "the images")
    assert str(error.value) == (f"cannot create {blocker / 'out'} (the images): "
                                f"{blocker} is not a directory")


def test_the_default_cache_root_says_how_to_move_it(tmp_path, capsys, monkeypatch):
    """Without $MCRT_CACHE_DIR (a read-only home, say) the message names the
    default root and the variable that moves it."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.delenv("MCRT_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    code, err = _reference(tmp_path, capsys)
    assert code == 2 and f"{blocker} is not a directory" in err, err
    assert f"mcrt's cache {blocker / 'mcrt'}; $MCRT_CACHE_DIR moves it" in err, err
