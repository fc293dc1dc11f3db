"""``plantkg cert issue``: a client certificate of the plant CA for a resource (docs/security.md,
Client certificates).

The operator runs it on a machine that holds the plant CA (``--ca-dir``, as ``plantkg agent``'s)
and carries the written folder to the device: the key (0600), the certificate (common name the
resource's ``pk:id``, clientAuth) and the CA certificate. Only paths and the expiry are printed,
never the key.
"""

from __future__ import annotations

from pathlib import Path

import click


@click.group("cert")
def cert_command() -> None:
    """Client certificates of the plant CA (resources that say pk:clientCertificate true)."""


@cert_command.command("issue")
@click.argument("resource_id", metavar="RESOURCE_ID")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write RESOURCE_ID.key (0600), RESOURCE_ID.pem and ca.pem to "
                   "(made 0700 if missing).")
@click.option("--ca-dir", type=click.Path(file_okay=False, path_type=Path),
              help="The plant CA folder (ca.pem, ca.key 0600); created if missing.  "
                   "[default: $PLANTKG_CA_DIR, else $XDG_STATE_HOME/plantkg/ca]")
def issue_command(resource_id: str, out: Path, ca_dir: Path | None) -> int:
    """Issue RESOURCE_ID (its pk:id) a new key and client certificate of the plant CA.

    Each run makes a new key and certificate (90 days): run it again before the old one expires
    and replace the files on the device.
    """
    from engine.security.ca import ca_dir as find_ca_dir
    from engine.security.ca import load_or_create_ca
    from engine.security.client_cert import write_client_bundle

    bundle = write_client_bundle(load_or_create_ca(find_ca_dir(ca_dir)), resource_id, out)
    click.echo(f"issued {bundle.resource_id}: key {bundle.key_file} (0600, keep it secret), "
               f"certificate {bundle.cert_file}, CA {bundle.ca_file}; "
               f"valid until {bundle.not_after:%Y-%m-%d %H:%M} UTC")
    return 0
