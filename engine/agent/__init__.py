"""The agent: an HTTP daemon, one per machine, that runs and supervises the brokers of that
machine through drivers (see docs/agent.md). The engine talks to it with
:class:`engine.agent.client.AgentClient`."""
