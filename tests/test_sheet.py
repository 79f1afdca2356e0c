"""Contact sheets and signal plots: one stick figure per keypose, signals the methods use."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from streamkey.bvh import read_bvh
from streamkey.cli import main
from streamkey.errors import UsageError
from streamkey.methods import offline_method
from streamkey.sheet import FIGURE_COLOR, contact_sheet, driving_signals, keypose_points
from streamkey.signal import local_minima

ROOT = Path(__file__).resolve().parents[1]


def figures_in_png(path: Path) -> int:
    """Count the stick figures of a sheet: connected blobs of the figure colour."""
    import matplotlib.image

    rgb = matplotlib.image.imread(path)[..., :3]
    target = np.array([int(FIGURE_COLOR[i : i + 2], 16) / 255 for i in (1, 3, 5)])
    ink = np.linalg.norm(rgb - target, axis=-1) < 0.25
    ink = ndimage.binary_dilation(ink, iterations=2)  # join anti-aliased line ends
    labels, n = ndimage.label(ink, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel())[1:]
    return int(np.count_nonzero(sizes > 50))


@pytest.fixture(scope="module")
def walk(data_dir: Path):  # type: ignore[no-untyped-def]
    return read_bvh(data_dir / "07_01.bvh")


@pytest.mark.parametrize("method", ["saliency", "speed"])
def test_sheet_command_draws_one_figure_per_keyframe_of_07_01(
        walk, data_dir: Path, tmp_path: Path, method: str) -> None:
    keys = offline_method(method)(walk)
    out = tmp_path / f"sheet_{method}.png"
    assert main(["sheet", str(data_dir / "07_01.bvh"), "--method", method, "-o", str(out)]) == 0
    assert figures_in_png(out) == len(keys) >= 3
    if method == "saliency":
        docs = ROOT / "docs" if os.environ.get("STREAMKEY_UPDATE_DOCS") else ROOT / "results"
        docs.mkdir(exist_ok=True)
        shutil.copyfile(out, docs / "sheet_07_01.png")


def test_sheet_wraps_rows_and_keeps_one_figure_per_frame(walk, tmp_path: Path) -> None:
    frames = [20, 60, 100, 140, 180, 220, 260]
    result = contact_sheet(walk, frames, tmp_path / "s.png", columns=3, view="side")
    assert result.figures == 7 and result.frames == frames
    assert figures_in_png(tmp_path / "s.png") == 7


def test_keyposes_are_body_aligned_so_a_walk_stays_in_place(walk) -> None:
    pts = keypose_points(walk, np.arange(walk.first_frame, walk.n_frames, 20), view="front")
    # the root sits at x = 0 in every pose although the actor walks several metres
    np.testing.assert_allclose(pts[:, 0, 0], 0.0, atol=1e-9)
    assert np.ptp(pts[..., 1]) == pytest.approx(1.0, abs=0.25)  # about one body height tall


def test_speed_keyframes_sit_at_minima_of_the_plotted_speed(walk, tmp_path: Path) -> None:
    keys = offline_method("speed")(walk)
    speed = driving_signals(walk)["speed"]
    minima = local_minima(speed[walk.first_frame + 1 :]) + walk.first_frame + 1
    for f in keys.frames:
        assert np.abs(minima - f).min() <= 3, f"speed key {f} is not at a speed minimum"
    assert main(["plot", str(ROOT.parent / "shared" / "data" / "cmu" / "07_01.bvh"),
                 "--method", "all", "-o", str(tmp_path / "plot.png")]) == 0
    assert (tmp_path / "plot.png").stat().st_size > 10_000


def test_missing_matplotlib_gives_the_install_hint(walk, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    with pytest.raises(UsageError, match=r"install streamkey\[plot\]"):
        contact_sheet(walk, [10, 20], tmp_path / "s.png")
    code = main(["sheet", str(ROOT.parent / "shared" / "data" / "cmu" / "07_01.bvh"),
                 "-o", str(tmp_path / "s.png")])
    err = capsys.readouterr().err
    assert code == 2 and "install streamkey[plot]" in err and "Traceback" not in err


def _boxes(fig, texts):
    renderer = fig.canvas.get_renderer()
    return [t.get_window_extent(renderer) for t in texts if t.get_text()]


def test_contact_sheet_without_a_path_is_a_figure_with_the_title_clear_of_the_captions(
        walk) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    keys = offline_method("saliency")(walk)
    fig = contact_sheet(walk, keys, title="07_01: saliency keyposes", columns=6)
    assert isinstance(fig, Figure)
    FigureCanvasAgg(fig)
    drawn = [ax for ax in fig.axes if ax.collections]
    assert len(drawn) == len(keys)
    captions = [ax.title for ax in drawn]
    assert [c.get_text().split(" ")[0] for c in captions] == [str(f) for f in keys.frames]
    assert min(c.get_fontsize() for c in captions) >= 8
    title, = _boxes(fig, [fig._suptitle])
    boxes = _boxes(fig, captions)
    assert all(not title.overlaps(b) and title.y0 > b.y1 for b in boxes)
    assert all(not a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])


def test_sheet_per_page_writes_numbered_pages_holding_every_keypose(
        walk, data_dir: Path, tmp_path: Path, capsys) -> None:
    keys = offline_method("saliency")(walk)  # 18 keyposes: three pages of six at most
    assert 12 < len(keys) <= 18
    out = tmp_path / "walk.png"
    assert main(["sheet", str(data_dir / "07_01.bvh"), "--per-page", "6", "--columns", "3",
                 "-o", str(out)]) == 0
    pages = [tmp_path / f"walk-p{i}.png" for i in (1, 2, 3)]
    assert sorted(tmp_path.iterdir()) == sorted(pages)
    assert [figures_in_png(p) for p in pages] == [6, 6, len(keys) - 12]
    err = capsys.readouterr().err
    assert all(f"wrote {p}" in err for p in pages) and f"{len(keys)} keyposes on 3 page" in err
    result = contact_sheet(walk, keys.frames[:5], out, per_page=8)
    assert result.pages == [out] and figures_in_png(out) == 5  # one page: no suffix
    assert main(["sheet", str(data_dir / "07_01.bvh"), "--per-page", "-1", "-o", str(out)]) == 2


def test_plot_all_draws_no_pose_markers_for_curvefits_per_channel_keys(walk) -> None:
    from matplotlib.colors import to_hex

    from streamkey.batch import extract_motion
    from streamkey.methods import OFFLINE_METHODS
    from streamkey.sheet import METHOD_COLORS, plot_signals

    results = extract_motion(walk, list(OFFLINE_METHODS))
    fig = plot_signals(walk, results)
    signal_axes = fig.axes[:-1]
    for method, keys in results.items():
        color = METHOD_COLORS[method]
        markers = [ln for ax in signal_axes for ln in ax.lines if to_hex(ln.get_color()) == color]
        want = 0 if method == "curvefit" else len(keys) * len(signal_axes)
        assert len(markers) == want, method
    lanes = [t.get_text() for t in fig.axes[-1].get_yticklabels()]
    assert f"curvefit ({len(results['curvefit'])}, per channel)" in lanes
