"""plantkg's NGSI-v2 context broker: the FIWARE Orion API, with the context kept as RDF.

A process the agent runs like a broker (``python -m engine.context_broker``), see
docs/context-broker.md. :mod:`engine.context_broker.contract` is what its parts share: the tenant
of a request, the change event a write produces, and the listener that receives it (the
subscription engine).
"""
