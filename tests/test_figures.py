"""The shared figure helpers: what a reader sees is inside the picture."""

from __future__ import annotations

from rtcal.deliverables.figures import legend_below, plt


def test_a_legend_of_long_labels_stays_inside_the_figure(tmp_path):
    """The multi-station figure's labels are ~90 characters: unwrapped, its legend ran past both edges."""
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8.5, 8.2), layout="constrained")
    long = "stations together (one dead path per tracking segment), bars ±U (k = 2) — recommended"
    for k in range(5):
        ax.plot([0, 1], [k, k], label=f"ECC {k}, {long}")
        ax2.plot([0, 1], [k, -k], label=f"Δθ {k}, {long}")
    legend_below(fig)
    fig.savefig(tmp_path / "f.png", dpi=120)
    renderer = fig.canvas.get_renderer()
    box, page = fig.legends[0].get_window_extent(renderer), fig.bbox
    assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0, (box, page)
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert all("k\u00a0=\u00a02" in t for t in texts) and any("\n" in t for t in texts)
    plt.close(fig)
