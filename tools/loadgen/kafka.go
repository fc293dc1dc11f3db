package main

// kafka-consume: reads a topic from the beginning or from its end offsets at start, with the
// same accounting as mqtt-sub. No batch-wait: a fetch asks for at least one byte, so a poll
// returns as soon as records arrive.

import (
	"context"
	"errors"
	"flag"
	"fmt"
	"net"
	"strings"
	"time"

	"github.com/twmb/franz-go/pkg/kadm"
	"github.com/twmb/franz-go/pkg/kgo"
	"github.com/twmb/franz-go/pkg/sasl/scram"
)

type kafkaOptions struct {
	common
	brokers string
	from    string
	sasl    string
}

func (o *kafkaOptions) clientOpts() ([]kgo.Opt, error) {
	if o.brokers == "" {
		return nil, errors.New("--brokers is required")
	}
	if err := o.validate(); err != nil {
		return nil, err
	}
	seeds := strings.Split(o.brokers, ",")
	host, _, err := net.SplitHostPort(seeds[0])
	if err != nil {
		return nil, fmt.Errorf("--brokers %q: %w", o.brokers, err)
	}
	opts := []kgo.Opt{kgo.SeedBrokers(seeds...), kgo.FetchMinBytes(1), kgo.FetchMaxWait(500 * time.Millisecond),
		kgo.DialTimeout(30 * time.Second)}
	tlsCfg, err := o.tlsConfig(host)
	if err != nil {
		return nil, err
	}
	if tlsCfg != nil {
		opts = append(opts, kgo.DialTLSConfig(tlsCfg))
	}
	switch o.sasl {
	case "":
		if o.username != "" {
			return nil, errors.New("--username needs --sasl SCRAM-SHA-512 for Kafka")
		}
	case "SCRAM-SHA-512":
		if o.username == "" {
			return nil, errors.New("--sasl SCRAM-SHA-512 needs --username")
		}
		pw, err := o.password()
		if err != nil {
			return nil, err
		}
		opts = append(opts, kgo.SASL(scram.Auth{User: o.username, Pass: pw}.AsSha512Mechanism()))
	default:
		return nil, fmt.Errorf("--sasl %q: only SCRAM-SHA-512 is supported", o.sasl)
	}
	return opts, nil
}

// endOffsets polls the topic's end offsets until it exists or the deadline passes.
func endOffsets(ctx context.Context, opts []kgo.Opt, topic string) (map[string]map[int32]kgo.Offset, error) {
	admin, err := kgo.NewClient(opts...)
	if err != nil {
		return nil, err
	}
	defer admin.Close()
	adm := kadm.NewClient(admin)
	for {
		listed, err := adm.ListEndOffsets(ctx, topic)
		if err == nil {
			err = listed.Error()
		}
		if err == nil && len(listed[topic]) > 0 {
			return listed.KOffsets(), nil
		}
		select {
		case <-ctx.Done():
			return nil, fmt.Errorf("end offsets of %s: %v (deadline passed)", topic, err)
		case <-time.After(200 * time.Millisecond):
		}
	}
}

func runKafkaConsume(args []string) int {
	const mode = "kafka-consume"
	var o kafkaOptions
	fs := flag.NewFlagSet(mode, flag.ContinueOnError)
	o.common.register(fs)
	fs.StringVar(&o.brokers, "brokers", "", "Kafka bootstrap host:port[,host:port] (required)")
	fs.StringVar(&o.from, "from", "beginning", "beginning, or end (the end offsets when it starts)")
	fs.StringVar(&o.sasl, "sasl", "", "SASL mechanism: SCRAM-SHA-512 (login from --username and the password)")
	if err := fs.Parse(args); err != nil {
		return 2
	}
	opts, err := o.clientOpts()
	if err != nil {
		return fail(mode, err)
	}
	ctx, cancel := context.WithTimeout(context.Background(), o.deadline)
	defer cancel()
	switch o.from {
	case "beginning":
		opts = append(opts, kgo.ConsumeTopics(o.topic), kgo.ConsumeResetOffset(kgo.NewOffset().AtStart()))
	case "end":
		offsets, err := endOffsets(ctx, opts, o.topic)
		if err != nil {
			return fail(mode, err)
		}
		opts = append(opts, kgo.ConsumePartitions(offsets))
	default:
		return fail(mode, fmt.Errorf("--from %q: use beginning or end", o.from))
	}
	client, err := kgo.NewClient(opts...)
	if err != nil {
		return fail(mode, err)
	}
	defer client.Close()
	emit(map[string]any{"event": "ready", "mode": mode})

	t := newTally(o.count)
	var first, last time.Time
	var malformed uint64
	var fetchErr error
	for !t.complete() && ctx.Err() == nil {
		fetches := client.PollFetches(ctx)
		now := time.Now()
		fetches.EachError(func(topic string, p int32, err error) {
			if !errors.Is(err, context.DeadlineExceeded) && !errors.Is(err, context.Canceled) && fetchErr == nil {
				fetchErr = fmt.Errorf("fetch %s[%d]: %w", topic, p, err)
			}
		})
		fetches.EachRecord(func(r *kgo.Record) {
			index, sent, err := decodePayload(r.Value)
			if err != nil {
				malformed++
				return
			}
			if first.IsZero() {
				first = now
			}
			if t.add(index, now.Sub(sent)) {
				last = now
			}
		})
		if fetchErr != nil {
			break
		}
	}
	fields := latencySummary(t.latencies)
	fields["count"] = o.count
	fields["received"] = t.distinct
	fields["missing"] = o.count - t.distinct
	fields["duplicates"] = t.duplicates
	fields["foreign"] = t.foreign
	fields["malformed"] = malformed
	fields["timed_out"] = !t.complete() && fetchErr == nil
	if fetchErr != nil {
		fields["error"] = fetchErr.Error()
	}
	elapsed := time.Duration(0)
	if !first.IsZero() {
		elapsed = last.Sub(first)
		fields["first_unix_ns"] = first.UnixNano()
		fields["last_unix_ns"] = last.UnixNano()
	}
	report(mode, fields, t.distinct, elapsed)
	if fetchErr != nil {
		return 2
	}
	if !t.complete() {
		return 1
	}
	return 0
}
