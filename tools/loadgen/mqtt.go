package main

// MQTT modes: a QoS-1 publisher with at most W messages in flight (publish→PUBACK latency) and
// a QoS-1 subscriber (distinct indexes, duplicates, end-to-end latency from the payload's time).

import (
	"errors"
	"flag"
	"fmt"
	"net"
	"os"
	"sync"
	"sync/atomic"
	"time"

	mqtt "github.com/eclipse/paho.mqtt.golang"
)

type mqttOptions struct {
	common
	broker   string
	clientID string
}

func (o *mqttOptions) register(fs *flag.FlagSet) {
	o.common.register(fs)
	fs.StringVar(&o.broker, "broker", "", "MQTT broker host:port (required)")
	fs.StringVar(&o.clientID, "client-id", "", "client id (default: loadgen-<mode>-<pid>)")
}

// connect opens a clean session with a 30 s CONNECT timeout and no automatic reconnect: a
// benchmark that lost its connection should say so, not hide it.
func (o *mqttOptions) connect(mode string) (mqtt.Client, error) {
	if o.broker == "" {
		return nil, errors.New("--broker is required")
	}
	if err := o.validate(); err != nil {
		return nil, err
	}
	host, _, err := net.SplitHostPort(o.broker)
	if err != nil {
		return nil, fmt.Errorf("--broker %q: %w", o.broker, err)
	}
	tlsCfg, err := o.tlsConfig(host)
	if err != nil {
		return nil, err
	}
	scheme := "tcp"
	if tlsCfg != nil {
		scheme = "ssl"
	}
	id := o.clientID
	if id == "" {
		id = fmt.Sprintf("loadgen-%s-%d", mode, os.Getpid())
	}
	opts := mqtt.NewClientOptions().AddBroker(scheme + "://" + o.broker).SetClientID(id).
		SetCleanSession(true).SetAutoReconnect(false).SetConnectRetry(false).
		SetConnectTimeout(30 * time.Second).SetKeepAlive(60 * time.Second).
		SetOrderMatters(false).SetWriteTimeout(30 * time.Second)
	if tlsCfg != nil {
		opts.SetTLSConfig(tlsCfg)
	}
	if o.username != "" {
		pw, err := o.password()
		if err != nil {
			return nil, err
		}
		opts.SetUsername(o.username).SetPassword(pw)
	}
	client := mqtt.NewClient(opts)
	token := client.Connect()
	if !token.WaitTimeout(o.deadline) {
		return nil, fmt.Errorf("no CONNACK from %s within %s", o.broker, o.deadline)
	}
	if err := token.Error(); err != nil {
		return nil, fmt.Errorf("connect to %s: %w", o.broker, err)
	}
	return client, nil
}

func runMQTTPub(args []string) int {
	const mode = "mqtt-pub"
	var o mqttOptions
	var window, size int
	fs := flag.NewFlagSet(mode, flag.ContinueOnError)
	o.register(fs)
	fs.IntVar(&window, "window", 100, "at most this many messages awaiting PUBACK")
	fs.IntVar(&size, "size", 64, "payload bytes (at least 16: index and send time)")
	if err := fs.Parse(args); err != nil {
		return 2
	}
	if window < 1 {
		return fail(mode, errors.New("--window must be at least 1"))
	}
	client, err := o.connect(mode)
	if err != nil {
		return fail(mode, err)
	}
	defer client.Disconnect(250)

	// W workers, each publishing one message and waiting for its PUBACK: at most W in flight.
	var next atomic.Uint64
	var acked atomic.Uint64
	var mu sync.Mutex
	var firstErr error
	latencies := make([]time.Duration, 0, o.count)
	deadline := time.Now().Add(o.deadline)
	start := time.Now()
	var wg sync.WaitGroup
	for w := 0; w < window; w++ {
		wg.Add(1)
		go func() {
			defer wg.Done()
			for {
				i := next.Add(1) - 1
				if i >= o.count || time.Now().After(deadline) {
					return
				}
				sent := time.Now()
				token := client.Publish(o.topic, 1, false, encodePayload(i, sent, size))
				ok := token.WaitTimeout(time.Until(deadline))
				took := time.Since(sent)
				mu.Lock()
				if !ok && firstErr == nil {
					firstErr = fmt.Errorf("no PUBACK for message %d before the deadline", i)
				} else if token.Error() != nil && firstErr == nil {
					firstErr = fmt.Errorf("publish %d: %w", i, token.Error())
				} else if ok && token.Error() == nil {
					latencies = append(latencies, took)
					acked.Add(1)
				}
				stop := firstErr != nil
				mu.Unlock()
				if stop {
					return
				}
			}
		}()
	}
	wg.Wait()
	elapsed := time.Since(start)
	fields := latencySummary(latencies)
	fields["sent"] = min(next.Load(), o.count)
	fields["acked"] = acked.Load()
	fields["count"] = o.count
	fields["start_unix_ns"] = start.UnixNano()
	if firstErr != nil {
		fields["error"] = firstErr.Error()
	}
	report(mode, fields, acked.Load(), elapsed)
	if acked.Load() != o.count {
		return 1
	}
	return 0
}

func runMQTTSub(args []string) int {
	const mode = "mqtt-sub"
	var o mqttOptions
	fs := flag.NewFlagSet(mode, flag.ContinueOnError)
	o.register(fs)
	var idle time.Duration
	fs.DurationVar(&idle, "idle", 0, "after the first delivery, stop when nothing new arrives for this long (0: only --deadline)")
	if err := fs.Parse(args); err != nil {
		return 2
	}
	client, err := o.connect(mode)
	if err != nil {
		return fail(mode, err)
	}
	defer client.Disconnect(250)

	t := newTally(o.count)
	var mu sync.Mutex
	var first, last time.Time
	var malformed uint64
	done := make(chan struct{})
	handler := func(_ mqtt.Client, msg mqtt.Message) {
		now := time.Now()
		index, sent, err := decodePayload(msg.Payload())
		mu.Lock()
		defer mu.Unlock()
		if err != nil {
			malformed++
			return
		}
		if first.IsZero() {
			first = now
		}
		if t.add(index, now.Sub(sent)) {
			last = now
			if t.complete() {
				close(done)
			}
		}
	}
	token := client.Subscribe(o.topic, 1, handler)
	if !token.WaitTimeout(o.deadline) {
		return fail(mode, fmt.Errorf("no SUBACK for %s within %s", o.topic, o.deadline))
	}
	if err := token.Error(); err != nil {
		return fail(mode, fmt.Errorf("subscribe %s: %w", o.topic, err))
	}
	if st, ok := token.(*mqtt.SubscribeToken); ok {
		if code := st.Result()[o.topic]; code >= 0x80 {
			return fail(mode, fmt.Errorf("subscription to %s refused (SUBACK code %#x)", o.topic, code))
		}
	}
	emit(map[string]any{"event": "ready", "mode": mode})
	timedOut := waitDone(done, o.deadline, idle, func() time.Time {
		mu.Lock()
		defer mu.Unlock()
		return last
	})
	mu.Lock()
	defer mu.Unlock()
	fields := latencySummary(t.latencies)
	fields["count"] = o.count
	fields["received"] = t.distinct
	fields["missing"] = o.count - t.distinct
	fields["duplicates"] = t.duplicates
	fields["foreign"] = t.foreign
	fields["malformed"] = malformed
	fields["timed_out"] = timedOut
	elapsed := time.Duration(0)
	if !first.IsZero() {
		elapsed = last.Sub(first)
		fields["first_unix_ns"] = first.UnixNano()
		fields["last_unix_ns"] = last.UnixNano()
	}
	report(mode, fields, t.distinct, elapsed)
	if timedOut {
		return 1
	}
	return 0
}

// waitDone waits for done, the deadline, or (idle > 0) idle time since the last new delivery;
// it reports whether it stopped before done. It polls the last delivery every 50 ms.
func waitDone(done <-chan struct{}, deadline, idle time.Duration, lastNew func() time.Time) bool {
	stop := time.After(deadline)
	tick := time.NewTicker(50 * time.Millisecond)
	defer tick.Stop()
	for {
		select {
		case <-done:
			return false
		case <-stop:
			return true
		case <-tick.C:
			if last := lastNew(); idle > 0 && !last.IsZero() && time.Since(last) > idle {
				return true
			}
		}
	}
}
