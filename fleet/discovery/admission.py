"""Admit a vehicle to a closed broker before it connects (``plantkg fleet admit``).

A closed Mosquitto lets in only its users, and a vehicle is a user once the plant gives it a
``pk:secretRef`` (docs/security.md, "The fleet on a closed broker"). Plug and play cannot make that
user by itself: the vehicle must log in before it is heard. Admission is a person's decision, kept
in the fleet manager's data directory like a pin or a rename:

- a new password (32 random bytes, URL-safe) in a file of the person's choosing, created here with
  mode 0600 and never written over: the vehicle's machine gets that file (``python -m fleet.sim
  --username agv-{serial} --secret-ref file:...``); no password is printed;
- the vehicle's record and Turtle (:class:`~fleet.discovery.records.VehicleRecord` with
  ``secret_ref`` and ``awaiting_description``): its identity (interface, manufacturer, serial),
  its channels, ``pk:secretRef "file:<the password file>"``, ``fleet:discovered false``, state
  ``OFFLINE``, no skills or properties yet.

A running fleet manager reloads the data directory within its poll interval and reconciles: the
broker gets the vehicle's user (named by its ``pk:id``, ``agv-<serial>``) with exactly its
channels' rights (rules A1/A2). When the vehicle says ONLINE the manager asks its factsheet; its
description fills the record in (skills, properties) and keeps the ``secret_ref``.
``plantkg fleet remove`` takes the admission back: the next reconcile removes the user.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from engine.whole_file import create_once
from fleet.discovery import model_api
from fleet.discovery.errors import DiscoveryError
from fleet.discovery.inbox import Interface
from fleet.discovery.records import DataDir, VehicleRecord, now_iso

PASSWORD_BYTES = 32


class AdmissionError(DiscoveryError):
    """A vehicle cannot be admitted: its identity is invalid, it is known already, or its
    password file cannot be made. Nothing was written."""


@dataclass(frozen=True)
class Admission:
    """What :func:`admit` wrote."""

    record: VehicleRecord
    turtle: Path          # the vehicle's Turtle in the data directory
    secret_file: Path     # its password, 0600
    user: str             # its user name on the broker (its pk:id)


def admit(data: DataDir, binding: dict[str, Any], interface: str, manufacturer: str, serial: str,
          secret_file: Path) -> Admission:
    """Admit the vehicle ``manufacturer``/``serial`` (module docstring). Refused, with nothing
    written, when its identity is invalid, the data directory knows it already, or
    ``secret_file`` exists or its folder does not."""
    if interface not in (i.value for i in Interface):
        raise AdmissionError(f"interface {interface!r} is not one of {', '.join(i.value for i in Interface)}",
                             hint="vda5050 for a VDA 5050 vehicle, paper-channels for the paper's five channels")
    try:
        description = model_api.admitted_description(interface, manufacturer, serial)
    except model_api.description_errors() as exc:
        raise AdmissionError(f"vehicle {manufacturer}/{serial} cannot be admitted: {exc}",
                             hint="give the serial and manufacturer the vehicle uses in its topics") from None
    secret_file = Path(secret_file).absolute()
    if not secret_file.parent.is_dir():
        raise AdmissionError(f"{secret_file}: its folder does not exist",
                             hint="make the folder (readable by you only), or choose another --secret-file")
    topic_manufacturer = manufacturer if interface == Interface.VDA5050.value else ""
    record = VehicleRecord(interface=interface, manufacturer=manufacturer, serial=serial,
                           topic_manufacturer=topic_manufacturer, description=description, binding=binding,
                           connection_state="OFFLINE", discovered_at=now_iso(),
                           secret_ref=f"file:{secret_file}", awaiting_description=True)
    with data.lock():
        ident = (record.interface, record.topic_manufacturer, record.serial)  # what its messages name
        known = [r for r in data.records()
                 if r.stem == record.stem or (r.interface, r.topic_manufacturer, r.serial) == ident]
        if known:
            what = "admitted" if known[0].awaiting_description else "discovered"
            raise AdmissionError(f"vehicle {record.label} is {what} already ({data.turtle_path(known[0])})",
                                 hint=f"plantkg fleet remove {record.label} first to admit it again with a new password")
        password = secrets.token_urlsafe(PASSWORD_BYTES)
        if not create_once(secret_file, password + "\n", mode=0o600, durable=True):
            raise AdmissionError(f"{secret_file} exists: admission makes a new password and never writes over one",
                                 hint="remove the file (a vehicle that uses it loses access), or choose another --secret-file")
        try:
            turtle = data.save(record)
        except BaseException:
            secret_file.unlink(missing_ok=True)
            raise
    return Admission(record, turtle, secret_file, user=model_api.resource_id(serial))

