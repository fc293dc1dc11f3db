"""The plant's web face: a dashboard, a SPARQL 1.1 endpoint and a small JSON API (``plantkg serve``).

Top layer: it may import anything in ``engine`` and ``kg``; nothing imports it (import-linter).
See docs/web.md.
"""
