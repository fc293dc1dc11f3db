"""``plantkg serve``'s control socket: a command of the same user runs in the warm server.

``plantkg apply`` starts cold: imports, shapes, TBox and rules cost far more than the apply of a
small plant (benchmarks/results/deploy.md, rows plantkg-cli and plantkg-cli-served). A ``plantkg serve`` process keeps all of that warm. When one
serves exactly the files (and agents file and owner) an ``apply`` names, the command hands its
work to it over a Unix socket only its user can open, and prints what comes back: the same plan,
progress, prompt, summary and exit code as when it runs alone.

- :mod:`engine.control.address`: where the socket of a served plant is (stdlib only);
- :mod:`engine.control.wire`: the messages, one JSON object per line (stdlib only);
- :mod:`engine.control.client`: the command's side (stdlib only: it must start at once);
- :mod:`engine.control.server`: the server's side, in ``plantkg serve``.
"""
