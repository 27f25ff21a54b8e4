"""A self-contained HTML page: sections of text, tables and base64-embedded PNG figures."""

import base64
import html
import io
import os

from ..io.output import write_atomic

CSS = """
body{font-family:DejaVu Sans,Arial,sans-serif;margin:24px auto;max-width:1100px;color:#222}
h1{font-size:22px;border-bottom:2px solid #446;padding-bottom:4px}
h2{font-size:18px;margin-top:28px;color:#335}
table{border-collapse:collapse;font-size:12px;margin:8px 0}
td,th{border:1px solid #bbb;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#eef}
td.num{text-align:right;font-family:DejaVu Sans Mono,monospace}
img{max-width:100%;display:block;margin:6px 0}
.warn{background:#fff4e0;border-left:4px solid #e90;padding:4px 8px;margin:4px 0}
.note{background:#eef6ff;border-left:4px solid #48c;padding:4px 8px;margin:4px 0}
.meta{color:#555;font-size:13px}
"""


def png_bytes(fig, dpi=90):
    """Return the PNG bytes of a matplotlib ``Figure`` (Agg canvas, no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=dpi, bbox_inches='tight', pad_inches=0.12)
    return buf.getvalue()


class Page:
    """An HTML page built section by section; figures are kept for ``--png-dir`` too."""

    def __init__(self, title):
        self.title = title
        self.parts = []
        self.figures = []          # (name, png bytes)

    def h2(self, text, anchor):
        """Start a section with an id (the tests look sections up by id)."""
        self.parts.append(f'<h2 id="{html.escape(anchor)}">{html.escape(text)}</h2>')

    def p(self, text, cls=None):
        """Add a paragraph of plain text (escaped)."""
        c = f' class="{cls}"' if cls else ''
        self.parts.append(f'<p{c}>{html.escape(text)}</p>')

    def table(self, head, rows, num_cols=()):
        """Add a table; cells are escaped; ``num_cols`` are right-aligned."""
        out = ['<table><tr>' + ''.join(f'<th>{html.escape(str(h))}</th>' for h in head)
               + '</tr>']
        for r in rows:
            out.append('<tr>' + ''.join(
                f'<td{" class=num" if j in num_cols else ""}>{html.escape(str(c))}</td>'
                for j, c in enumerate(r)) + '</tr>')
        self.parts.append(''.join(out) + '</table>')

    def figure(self, name, fig, alt):
        """Embed a matplotlib figure as a base64 PNG and keep it as ``name``.png."""
        data = png_bytes(fig)
        self.figures.append((name, data))
        b64 = base64.b64encode(data).decode('ascii')
        self.parts.append(f'<img alt="{html.escape(alt)}" data-name="{html.escape(name)}" '
                          f'src="data:image/png;base64,{b64}">')

    def render(self):
        """Return the page text."""
        return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
                f'<title>{html.escape(self.title)}</title><style>{CSS}</style></head><body>'
                f'<h1>{html.escape(self.title)}</h1>\n' + '\n'.join(self.parts)
                + '\n</body></html>\n')

    def png_paths(self, png_dir):
        """Return the PNG files ``write`` would write into ``png_dir``."""
        return [os.path.join(png_dir, name + '.png') for name, _ in self.figures]

    def write(self, html_path=None, png_dir=None):
        """Write the page and/or the figures (each atomically); returns the paths written."""
        out = []
        if html_path:
            write_atomic(html_path, self.render())
            out.append(html_path)
        if png_dir:
            os.makedirs(png_dir, exist_ok=True)
            for (_, data), p in zip(self.figures, self.png_paths(png_dir)):
                write_atomic(p, data)
                out.append(p)
        return out
