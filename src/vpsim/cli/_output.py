"""What the commands print: no number without meaning (the helpers live in :mod:`vpsim.jsonsafe`, which
the library's own JSON uses too)."""

from ..errors import VpsimError
from ..jsonsafe import dumps, json_safe, number, reason

__all__ = ["dumps", "json_safe", "number", "reason", "save_plot"]


def save_plot(draw, path) -> None:
    """Draw a figure with ``draw()`` (which returns its axes) off screen and write it to ``path`` (the
    format from the extension); a path that cannot be written, or an extension no format has, is one line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax = draw()
    try:
        ax.figure.tight_layout()
        ax.figure.savefig(path, dpi=120)
    except (OSError, ValueError) as exc:
        raise VpsimError(f"--plot {path}: cannot write ({getattr(exc, 'strerror', None) or exc})") from None
    finally:
        plt.close(ax.figure)
