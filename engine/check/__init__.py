"""``plantkg check``: does data really flow from each resource to every broker that must carry it?

The first paper's last step, done by the machine. :mod:`.flows` lists the flows of a plant (pure:
desired state + who publishes what), :mod:`.publications` reads who publishes what from the graph,
:mod:`.watch` subscribes at every broker involved (and publishes marked probes with ``--probe``),
:mod:`.verdict` judges what arrived (pure), :mod:`.report` renders it as text or typed JSON.
"""
