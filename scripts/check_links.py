"""Every internal link of the built docs site points at a file that exists.

    .venv/bin/python scripts/check_links.py [docs/_build/html]

Reads every HTML page of the build, follows each relative ``href`` and ``src``
(external addresses and pure ``#anchors`` aside) and checks the target file
and, for ``page.html#anchor``, the anchor on that page. Exit 1 with one line
per broken link.
"""

from __future__ import annotations

import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k in ("href", "src") and v and tag in ("a", "img", "link", "script"):
                self.links.append(v)
            if k == "id" and v:
                self.ids.add(v)


def parse(page: Path) -> _Links:
    p = _Links()
    p.feed(page.read_text(encoding="utf-8", errors="replace"))
    return p


def broken(site: Path) -> list[str]:
    pages = {p.resolve(): parse(p) for p in site.rglob("*.html")}
    out = []
    for page, info in pages.items():
        for link in info.links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or link.startswith(("mailto:", "data:", "javascript:")):
                continue
            target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
            if parts.path.endswith("/"):
                target = target / "index.html"
            if not target.exists():
                out.append(f"{page.relative_to(site.resolve())}: {link} (no such file)")
            elif parts.fragment and target.suffix == ".html":
                ids = pages[target].ids if target in pages else parse(target).ids
                if parts.fragment not in ids:
                    out.append(f"{page.relative_to(site.resolve())}: {link} (no such anchor)")
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    site = Path(argv[0] if argv else "docs/_build/html")
    if not site.is_dir():
        print(f"check_links: {site} is not a built site; run `make docs` first", file=sys.stderr)
        return 2
    bad = broken(site)
    for line in bad:
        print(line)
    n = sum(1 for _ in site.rglob("*.html"))
    print(f"check_links: {len(bad)} broken internal link(s) in {n} pages")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
