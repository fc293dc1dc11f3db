"""A plant whose context broker has ``pk:tls true`` (issue 13), for a module of integration tests.

``plantkg apply`` of a plant file through a real agent (127.0.0.3) running a closed Mosquitto and
the context broker, whose API then speaks HTTPS only with a plant-CA certificate for its address;
``plantkg destroy`` and the agent's stop after the module. The AGV is a user of Mosquitto (its
password in the agent's environment), the planner a principal of the context broker (its token in
a 0600 file). test_context_broker_tls checks the broker itself; test_fleet_planner_tls the task
planner against it. A module's fixture says only ``with tls_plant(folder) as plant: yield plant``.
"""

from __future__ import annotations

import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
import requests

from engine.security import ca
from tests.integration.agents import AgentFleet, Deployment, deployment, secret_files

filip_cb = pytest.importorskip("filip.clients.ngsi_v2")
from filip.models.base import FiwareHeader  # noqa: E402

HOST = "127.0.0.3"
STATUS_ID = "urn:ngsi-ld:AgvStatus:1"
AGV_ENV = "PLANTKG_TEST_CB_TLS_AGV_PW"

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://example.org/cb-tls#> .
:mq a pk:Broker ; pk:id "mq" ; pk:name "mq" ; pk:brokerType "mosquitto" ; pk:ip "{host}" ;
    pk:port {mq_port} ; pk:hasTopic :status .
:cb a pk:Broker ; pk:id "cb" ; pk:name "cb" ; pk:brokerType "ngsi-v2" ; pk:ip "{host}" ;
    pk:port {cb_port} ; pk:tls true ; pk:hasTopic :status .
:status a pk:Topic ; pk:id "status" ; pk:name "agv/1/status" ; pk:qos 1 ; pk:entityId "{status_id}" ;
    pk:entityType "AgvStatus" .
:agv a pk:Resource ; pk:id "agv" ; pk:name "agv" ; pk:sendsTo :mq ; pk:publishes :status ;
    pk:secretRef "env:{agv_env}" .
:planner a pk:Resource ; pk:id "planner" ; pk:name "planner" ; pk:sendsTo :cb ; pk:subscribes :status ;
    pk:secretRef "file:{planner_file}" .
"""


@dataclass(frozen=True)
class Plant:
    deployed: Deployment
    agv_password: str
    planner_token: str

    @property
    def fleet(self) -> AgentFleet:
        return self.deployed.fleet

    @property
    def plant(self) -> Path:
        return self.deployed.plant

    @property
    def ports(self) -> dict[str, int]:
        return self.deployed.ports

    @property
    def url(self) -> str:
        return f"https://{HOST}:{self.ports['cb']}"

    @property
    def agent_token_file(self) -> Path:
        """The context broker's agent's token (plantkg's own principal: every right)."""
        return self.fleet.agents[HOST].state_dir / "token"

    def filip(self, token: str) -> filip_cb.ContextBrokerClient:
        session = requests.Session()
        session.verify = str(ca.ca_cert_file())  # the plant CA only
        session.trust_env = False  # else requests lets $REQUESTS_CA_BUNDLE override verify
        session.headers.update({"authorization": f"Bearer {token}"})
        return filip_cb.ContextBrokerClient(url=self.url, session=session, fiware_header=FiwareHeader())


@contextmanager
def tls_plant(tmp: Path) -> Iterator[Plant]:
    """The plant applied in ``tmp`` (agents, secrets, plant file there); destroyed after."""
    agv_password, planner_token = secrets.token_urlsafe(16), secrets.token_urlsafe(16)
    planner_file = secret_files(tmp / "secrets", {"planner": planner_token}) / "planner"

    def render(ports: dict[str, int]) -> str:
        return PLANT.format(host=HOST, mq_port=ports["mq"], cb_port=ports["cb"], status_id=STATUS_ID,
                            agv_env=AGV_ENV, planner_file=planner_file)

    with deployment(tmp, {"mq": HOST, "cb": HOST}, render, agent_env={AGV_ENV: agv_password}) as made:
        yield Plant(made, agv_password, planner_token)
