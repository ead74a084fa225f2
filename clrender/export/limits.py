"""What every WebGL2 implementation must offer (the spec's minimums), so an exported page
runs anywhere: a model that needs more is refused at export, naming the limit and the need.

The page checks the same values against the browser's own at load (web/gl.js).
References: WebGL 2.0 spec §3.7 / OpenGL ES 3.0 spec Table 6.28-6.33 (minimum values).
"""
from __future__ import annotations

# OpenGL ES 3.0 minimum values (the names of gl.getParameter).
MAX_TEXTURE_SIZE = 2048
MAX_3D_TEXTURE_SIZE = 256
MAX_ARRAY_TEXTURE_LAYERS = 256
MAX_TEXTURE_IMAGE_UNITS = 16
MAX_DRAW_BUFFERS = 4
MAX_UNIFORM_BLOCK_SIZE = 16384          # bytes
MAX_FRAGMENT_UNIFORM_VECTORS = 224

# Row width of the page's data textures (texels): one texture row, so a texture of ``n``
# texels is ceil(n / TEX_WIDTH) rows.
TEX_WIDTH = MAX_TEXTURE_SIZE


class ExportError(ValueError):
    """A model or dataset the page cannot take; the message names the file and the problem."""


def need(where: str, limit: str, value: int, needed: int, what: str) -> None:
    """Raise :class:`ExportError` when ``needed`` exceeds WebGL2's minimum ``value`` of
    ``limit``; ``what`` says which part of the model needs it."""
    if needed > value:
        raise ExportError(f"{where}: {what} needs {limit} >= {needed}; WebGL2 guarantees "
                          f"{value}, so the page would not run everywhere (export refused)")


def texture_rows(where: str, texels: int, what: str) -> int:
    """Rows of a TEX_WIDTH-wide texture holding ``texels`` texels, checked against
    MAX_TEXTURE_SIZE."""
    rows = max(1, -(-int(texels) // TEX_WIDTH))
    need(where, "MAX_TEXTURE_SIZE", MAX_TEXTURE_SIZE, rows,
         f"{what} ({texels} texels in rows of {TEX_WIDTH})")
    return rows
