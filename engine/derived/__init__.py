"""What ``engine.derive`` builds the desired state from, besides brokers and topics: broker users
and ACLs (``access``), one bridge spec per pair of brokers (``bridge_pairs``), the refusal of
bridge cycles (``bridge_cycles``) and a Kafka cluster's nodes (``kafka_cluster``)."""
