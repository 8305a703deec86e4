"""Figures of the paper reproduced from our own computations (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save(fig, path) -> list[str]:
    """Write ``path`` as PNG and PDF (suffix replaced); returns the file names."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = []
    for ext in (".png", ".pdf"):
        p = path.with_suffix(ext)
        fig.savefig(p, dpi=150, bbox_inches="tight")
        out.append(str(p))
    _plt().close(fig)
    return out


def plot_fig3(zsw, max_abs, status, path, limit: float = 50.0):
    """Paper Fig. 3: Z_sw(T^d) against max|lambda| (cases with max|lambda| < limit),
    stable cases in red."""
    plt = _plt()
    sel = np.isfinite(max_abs) & (max_abs < limit)
    st = sel & (status == "stable")
    un = sel & (status != "stable")
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.scatter(max_abs[un], zsw[un], s=4, c="0.5", label=f"unstable ({un.sum()})")
    ax.scatter(max_abs[st], zsw[st], s=10, c="red", label=f"stable ({st.sum()})")
    ax.axvline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel(r"max $|\lambda_{1,2}|$")
    ax.set_ylabel(r"$Z_{sw}(T^d)$ [m]  ($\Delta q_u = 10^{-2}$)")
    ax.set_title(r"Swing-foot height at $T^d$ vs. max $|\lambda|$ (9$^4$ grid)")
    ax.legend(loc="best", fontsize=8)
    return save(fig, path)


def plot_fig4(m2, m3, max_abs_1, max_abs_2, path, best=None):
    """Paper Fig. 4: stable domains of (M1(2), M1(3)) for both a = b = 0 groups, with
    the contour max|lambda| = 1 (log colour scale of max|lambda| behind it)."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), sharey=True)
    for k, (ax, mx) in enumerate(zip(axes, (max_abs_1, max_abs_2)), start=1):
        z = np.log10(np.clip(np.where(np.isfinite(mx), mx, 1e3), 1e-4, 1e3))
        im = ax.pcolormesh(m2, m3, z, shading="auto", cmap="viridis", vmin=-3, vmax=3)
        if np.nanmin(mx) < 1 < np.nanmax(np.where(np.isfinite(mx), mx, 1e3)):
            ax.contour(m2, m3, np.where(np.isfinite(mx), mx, 1e3), levels=[1.0], colors="red",
                       linewidths=1.5)
        if best is not None and best.get(k) is not None:
            b = best[k]
            ax.plot(b[1], b[2], "w*", ms=12, mec="k")
        ax.set_title(f"group {k}: contour max|λ| = 1 (red)")
        ax.set_xlabel("M1(2)")
    axes[0].set_ylabel("M1(3)")
    fig.colorbar(im, ax=axes, label="log10 max|λ|")
    return save(fig, path)
