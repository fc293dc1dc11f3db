"""Who may reach what, and how plantkg's own clients prove who they are (docs/security.md).

- :mod:`.secrets`: reading a secret a reference points to (``env:NAME``, ``file:/path``);
- :mod:`.principal_key`: the plant's principal key, from which the passwords of plantkg's own
  principals (bridges, the agent, the observers) are derived on every machine that needs them;
- :mod:`.principals`: the names of those principals;
- :mod:`.mqtt_client`: what a plantkg MQTT client sends to a broker (user name, password, TLS);
- :mod:`.ca`: the plant's certificate authority and the server certificates it issues;
- :mod:`.locations`: where a machine keeps the principal key and the CA.

Nothing here knows a driver, an agent or the web: drivers, agents, bridge workers, ``check``, the
dashboard and the fleet all import it.
"""
