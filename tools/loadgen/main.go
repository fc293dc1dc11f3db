// Command loadgen is plantkg's benchmark load generator: MQTT and Kafka clients in their own
// process, so a benchmark measures the brokers and bridges rather than its Python clients.
//
//	loadgen mqtt-pub      --broker host:port --topic T --n N --window W [--size B]
//	loadgen mqtt-sub      --broker host:port --topic T --n N [--deadline D]
//	loadgen kafka-consume --brokers host:port[,..] --topic T --n N [--from beginning|end]
//
// TLS: --ca-file (verify) or --no-verify; login: --username with the password from
// --password-file or $LOADGEN_PASSWORD (never argv, which ps shows). Every mode prints JSON
// lines on stdout: {"event":"ready"} once it listens (subscribers, consumers), then one report
// line with counts, elapsed_s, rate_per_s, latency_p50_ms/p99_ms/max_ms and its CPU seconds.
// Exit status: 0 when all N were counted, 1 when the deadline passed first, 2 on bad usage or
// a failed connection (the reason on stderr and in the report's "error").
package main

import (
	"fmt"
	"os"
)

var modes = map[string]func([]string) int{
	"mqtt-pub":      runMQTTPub,
	"mqtt-sub":      runMQTTSub,
	"kafka-consume": runKafkaConsume,
}

func main() {
	if len(os.Args) < 2 || modes[os.Args[1]] == nil {
		fmt.Fprintln(os.Stderr, "usage: loadgen mqtt-pub|mqtt-sub|kafka-consume [options] (-h for a mode's options)")
		os.Exit(2)
	}
	os.Exit(modes[os.Args[1]](os.Args[2:]))
}

// fail reports an error as a JSON line and on stderr; exit status 2.
func fail(mode string, err error) int {
	fmt.Fprintf(os.Stderr, "loadgen %s: %v\n", mode, err)
	emit(map[string]any{"mode": mode, "error": err.Error()})
	return 2
}
