"""The error pictures of a convert run (`cadbridge.tool.outputs.write_error_maps`).

References: the run's own list of files and folder; the sample grid of each tool
(``ToolResult.grid``), its per-element maximum taken here by sorting the samples, not by
`cadbridge.io.error_map.element_max`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.io.error_map import element_max, plot_error_map
from cadbridge.tool.pipeline import convert

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


@pytest.fixture(scope="module")
def ushape_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("maps") / "o"
    return out, convert(str(SAMPLES / "ushape_tools_nurbs.igs"), str(out), structured=True)


def test_every_tool_gets_both_error_maps(ushape_run):
    out, result = ushape_run
    assert len(result.tools) == 3
    for t in result.tools:
        for stem in ("shape_error_map", "normal_error_map"):
            name = f"{t.name}_{stem}.png"
            assert name in result.files
            assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("key", ["surface_error", "normal_error"])
def test_labelled_elements_are_the_worst_of_the_grid(ushape_run, tmp_path, key):
    """The labelled elements are those with the largest |error| on the tool's sample grid:
    reference = the grid sorted by (element, |error|), the last sample of each element."""
    _, result = ushape_run
    for t in result.tools:
        g = t.grid
        elem, err = np.asarray(g["element"]), np.abs(np.asarray(g[key]))
        assert np.all(np.isfinite(err))
        order = np.lexsort((err, elem))
        last = np.flatnonzero(np.r_[elem[order][1:] != elem[order][:-1], True])
        ref = np.zeros(t.nagata.n_elements)
        ref[elem[order][last]] = err[order][last]
        drawn = plot_error_map(tmp_path / f"{t.name}.png", t.nagata, element_max(elem, err, t.nagata.n_elements),
                               title="t", label="e")
        if ref.max() == 0:
            assert len(drawn.worst) == 0
            continue
        top = np.sort(ref)[::-1][: len(drawn.worst)]
        np.testing.assert_array_equal(drawn.values, top)
        np.testing.assert_array_equal(ref[drawn.worst], top)
        assert drawn.worst[0] in np.flatnonzero(ref == ref.max())


def _toolfile_element_corners(path: Path, element_id: int) -> np.ndarray:
    """Corner coordinates (k, 3) of element ``element_id`` (1-based, as written) parsed from
    the tool file's text (docs/toolfile.md: NODES and ELEMENTS records start with their id)."""
    lines = path.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("NODES "))
    n = int(lines[i].split()[1])
    nodes = {int(r.split()[0]): [float(v) for v in r.split()[1:4]] for r in lines[i + 1:i + 1 + n]}
    j = next(k for k, ln in enumerate(lines) if ln.startswith("ELEMENTS "))
    rec = next(r.split() for r in lines[j + 1:j + 1 + int(lines[j].split()[1])] if int(r.split()[0]) == element_id)
    return np.array([nodes[int(v)] for v in rec[2:2 + int(rec[1])]])


def test_labels_name_the_elements_of_the_tool_file(ushape_run, tmp_path):
    """A label is the element's number in the written tool file: the record with that id
    (1-based) has the corners of the element drawn as the worst."""
    out, result = ushape_run
    for t in result.tools:
        nm = t.nagata
        drawn = plot_error_map(tmp_path / f"{t.name}.png", nm,
                               element_max(t.grid["element"], t.grid["surface_error"], nm.n_elements),
                               title="t", label="e", negligible=1e-9)
        for e, label in zip(drawn.worst, drawn.labels):
            kind, loc = nm.element_kind[e], nm.element_local[e]
            conn = nm.tri_elements[loc] if kind == 3 else nm.quad_elements[loc]
            np.testing.assert_array_equal(_toolfile_element_corners(out / f"{t.name}.nagata", int(label)),
                                          nm.nodes[conn])
