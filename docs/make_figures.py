"""Regenerate the README figures: python docs/make_figures.py"""
from pathlib import Path

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle, FancyArrowPatch

from mjxsysid import theta as P
from mjxsysid.render.plots import plot_prior_marginals

HERE = Path(__file__).parent


def body_frame(path):
    fig, ax = plt.subplots(figsize=(5.2, 5.2))
    pos = P.ROTOR_DIRECTIONS
    for i, (x, y) in enumerate(pos):
        ax.plot([0, x], [0, y], color="0.3", lw=6, solid_capstyle="round", zorder=1)
        ccw = P.YAW_SIGNS[i] < 0
        col = "tab:red" if ccw else "tab:blue"
        ax.add_patch(Circle((x, y), 0.32, color=col, alpha=0.25, zorder=2))
        # spin arrow (seen from above): CCW for rotors 1, 3; CW for 2, 4
        a0, a1 = (200, 340) if ccw else (340, 200)
        t = np.deg2rad(np.linspace(a0, a1, 30))
        ax.plot(x + 0.22 * np.cos(t), y + 0.22 * np.sin(t), color=col, lw=1.5, zorder=3)
        ax.annotate("", xy=(x + 0.22 * np.cos(t[-1]), y + 0.22 * np.sin(t[-1])),
                    xytext=(x + 0.22 * np.cos(t[-3]), y + 0.22 * np.sin(t[-3])),
                    arrowprops=dict(arrowstyle="-|>", color=col, lw=1.5), zorder=3)
        ax.text(x, y, f"{i + 1}", ha="center", va="center", fontsize=18, weight="bold", zorder=4)
        ax.text(x * 1.48, y * 1.48, f"{P.ROTOR_NAMES[i]}\n{'CCW' if ccw else 'CW'}, yaw torque {'−' if ccw else '+'}κT",
                ha="center", va="center", fontsize=8)
    ax.add_patch(FancyArrowPatch((0, 0), (0.55, 0), arrowstyle="-|>", mutation_scale=18, color="k", lw=2, zorder=5))
    ax.add_patch(FancyArrowPatch((0, 0), (0, 0.55), arrowstyle="-|>", mutation_scale=18, color="k", lw=2, zorder=5))
    ax.text(0.6, -0.07, "$x_B$ (forward)", fontsize=11)
    ax.text(0.04, 0.6, "$y_B$ (left)", fontsize=11)
    ax.add_patch(Circle((0, 0), 0.05, fill=False, lw=1.5, zorder=5))
    ax.plot(0, 0, "k.", ms=4, zorder=6)
    ax.text(-0.28, -0.16, "$z_B$ up\n(out of page)", fontsize=9)
    ax.set_xlim(-1.45, 1.45)
    ax.set_ylim(-1.45, 1.45)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("mjxsysid body frame and rotor numbering (seen from above)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


if __name__ == "__main__":
    body_frame(HERE / "body_frame.png")
    th = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 20_000))
    plot_prior_marginals(th, HERE / "prior_marginals.png", mark=P.PAPER_HARDWARE)
    print("wrote docs/body_frame.png, docs/prior_marginals.png")
