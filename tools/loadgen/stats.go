package main

// Pure parts: the payload format, per-index accounting and latency percentiles.
// They carry no I/O, so they are unit-tested without brokers (stats_test.go).

import (
	"encoding/binary"
	"errors"
	"fmt"
	"math"
	"sort"
	"time"
)

// headerSize is the fixed head of every payload: index (uint64) then send time (unix ns, int64).
const headerSize = 16

// encodePayload writes index and send time into a payload of size bytes (at least headerSize).
func encodePayload(index uint64, sent time.Time, size int) []byte {
	if size < headerSize {
		size = headerSize
	}
	buf := make([]byte, size)
	binary.BigEndian.PutUint64(buf[0:8], index)
	binary.BigEndian.PutUint64(buf[8:16], uint64(sent.UnixNano()))
	return buf
}

// decodePayload reads index and send time back; a short payload is an error, not a zero.
func decodePayload(buf []byte) (uint64, time.Time, error) {
	if len(buf) < headerSize {
		return 0, time.Time{}, fmt.Errorf("payload of %d bytes is shorter than the %d-byte header", len(buf), headerSize)
	}
	index := binary.BigEndian.Uint64(buf[0:8])
	sent := time.Unix(0, int64(binary.BigEndian.Uint64(buf[8:16])))
	return index, sent, nil
}

// tally counts distinct indexes below n, duplicates and foreign (out-of-range) ones.
type tally struct {
	n          uint64
	seen       []bool
	distinct   uint64
	duplicates uint64
	foreign    uint64
	latencies  []time.Duration
}

func newTally(n uint64) *tally {
	return &tally{n: n, seen: make([]bool, n), latencies: make([]time.Duration, 0, n)}
}

// add records one delivery; it reports whether the index was new.
func (t *tally) add(index uint64, latency time.Duration) bool {
	if index >= t.n {
		t.foreign++
		return false
	}
	if t.seen[index] {
		t.duplicates++
		return false
	}
	t.seen[index] = true
	t.distinct++
	t.latencies = append(t.latencies, latency)
	return true
}

func (t *tally) complete() bool { return t.distinct == t.n }

// percentile is the nearest-rank percentile (q in [0, 100]) of the durations, in milliseconds.
func percentile(durations []time.Duration, q float64) (float64, error) {
	if len(durations) == 0 {
		return 0, errors.New("no latencies to summarise")
	}
	if q < 0 || q > 100 {
		return 0, fmt.Errorf("percentile %v outside [0, 100]", q)
	}
	sorted := append([]time.Duration(nil), durations...)
	sort.Slice(sorted, func(i, j int) bool { return sorted[i] < sorted[j] })
	rank := int(math.Ceil(q / 100 * float64(len(sorted))))
	if rank < 1 {
		rank = 1
	}
	return float64(sorted[rank-1]) / float64(time.Millisecond), nil
}

// latencySummary is p50, p99 and max in ms, or nulls when nothing was measured.
func latencySummary(durations []time.Duration) map[string]any {
	out := map[string]any{"latency_p50_ms": nil, "latency_p99_ms": nil, "latency_max_ms": nil}
	if len(durations) == 0 {
		return out
	}
	out["latency_p50_ms"], _ = percentile(durations, 50)
	out["latency_p99_ms"], _ = percentile(durations, 99)
	out["latency_max_ms"], _ = percentile(durations, 100)
	return out
}
