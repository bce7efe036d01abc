"""The output contract: paths checked before any work, atomic writes with unique temporary names."""

from __future__ import annotations

import os
import threading

import pytest

import secure3d
from secure3d.errors import OutputError
from secure3d.outputs import atomic_write_text, check_output_path, temporary_path
from secure3d.session import simulate


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"png": "DIR/"}, "is a directory"),
        ({"rrd": "DIR/"}, "is a directory"),
        ({"png": "DIR/x.jpg"}, "must end in .png"),
        ({"png": "/sys/x.png"}, "cannot"),
    ],
)
def test_simulate_refuses_an_unwritable_output_before_it_flies(maps_dir, tmp_path, kwargs, message):
    """These used to fail with a traceback after the whole flight, losing its results."""
    kwargs = {k: v.replace("DIR", str(tmp_path)) for k, v in kwargs.items()}
    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    with pytest.raises(OutputError, match=message):
        simulate(scenario, "secure", **kwargs)
    assert not list(tmp_path.rglob("*.part"))


def test_a_missing_output_folder_is_created(tmp_path):
    target = tmp_path / "new" / "deeper" / "run.png"
    assert check_output_path(target, (".png",), "png") == target
    assert target.parent.is_dir() and not list(target.parent.iterdir())


def test_temporary_names_are_unique_and_writes_are_atomic(tmp_path):
    target = tmp_path / "table.csv"
    names = {temporary_path(target) for _ in range(100)}
    assert len(names) == 100 and all(
        n.parent == tmp_path and n.name.endswith(".part") for n in names
    )
    texts = [f"writer {i}\n" * 1000 for i in range(8)]
    threads = [threading.Thread(target=atomic_write_text, args=(target, t)) for t in texts]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert target.read_text() in texts  # one whole file, never a mix or a truncation
    assert sorted(os.listdir(tmp_path)) == ["table.csv"]


def test_an_interrupted_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    """Figures, map files and tables share one writer: Ctrl-C in the middle of a write keeps the
    previous file whole and leaves no ``.part`` file behind."""
    import matplotlib.pyplot as plt

    from secure3d.mapping.occupancy import OccupancyMap
    from secure3d.outputs import atomic_output
    from secure3d.viz.figures import save_figure

    target = tmp_path / "table.csv"
    target.write_text("old\n")
    with pytest.raises(KeyboardInterrupt), atomic_output(target) as fh:
        fh.write(b"half a new")
        raise KeyboardInterrupt
    assert target.read_text() == "old\n"
    fig = plt.figure()
    try:
        save_figure(fig, tmp_path / "f.png")
    finally:
        plt.close(fig)
    OccupancyMap(resolution=0.1).write_bt(tmp_path / "m.bt")
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "m.bt").read_bytes().startswith(b"# Octomap OcTree binary file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "m.bt", "table.csv"]
