"""The SHACL shapes of the RabbitMQ broker type (entry point group ``plantkg.shapes``)."""
