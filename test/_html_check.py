"""Parse a report page: section ids and every embedded image, decoded."""

import base64
from html.parser import HTMLParser
import io

import numpy as np
from PIL import Image


class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.ids, self.images, self.external = [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if 'id' in a:
            self.ids.append(a['id'])
        if tag == 'img':
            self.images.append(a)
        for key in ('src', 'href'):
            v = a.get(key) or ''
            if v and not v.startswith('data:') and not v.startswith('#'):
                self.external.append(v)


def parse_report(text):
    """Return (section ids, [(name, decoded RGB array)]); asserts self-containedness."""
    page = _Page()
    page.feed(text)
    page.close()
    assert not page.external, f'the page refers to external resources: {page.external}'
    images = []
    for a in page.images:
        src = a['src']
        assert src.startswith('data:image/png;base64,'), src[:40]
        img = Image.open(io.BytesIO(base64.b64decode(src.split(',', 1)[1], validate=True)))
        img.load()
        arr = np.asarray(img.convert('RGB'))
        assert arr.shape[0] > 100 and arr.shape[1] > 100
        assert arr.std() > 5, f'{a.get("data-name")} is blank'
        images.append((a.get('data-name'), arr))
    return page.ids, images
