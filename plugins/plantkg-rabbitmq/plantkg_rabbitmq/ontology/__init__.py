"""The ontology terms of the RabbitMQ broker type (entry point group ``plantkg.ontology``)."""
