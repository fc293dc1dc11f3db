"""RabbitMQ as a plantkg broker type: a driver (``plantkg.drivers``) and its shapes
(``plantkg.shapes``), installed as a package of its own. See README.md."""
