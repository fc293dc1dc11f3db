package main

import (
	"testing"
	"time"
)

func TestPayloadRoundTrip(t *testing.T) {
	sent := time.Unix(1700000000, 123456789)
	buf := encodePayload(42, sent, 64)
	if len(buf) != 64 {
		t.Fatalf("payload is %d bytes, want 64", len(buf))
	}
	index, got, err := decodePayload(buf)
	if err != nil || index != 42 || !got.Equal(sent) {
		t.Fatalf("decoded (%d, %v, %v), want (42, %v, nil)", index, got, err, sent)
	}
	if n := len(encodePayload(1, sent, 3)); n != headerSize {
		t.Fatalf("a size below the header gives %d bytes, want %d", n, headerSize)
	}
}

func TestShortPayloadIsAnError(t *testing.T) {
	if _, _, err := decodePayload([]byte("short")); err == nil {
		t.Fatal("a 5-byte payload decoded without error")
	}
}

func TestTallyCountsDistinctDuplicatesForeign(t *testing.T) {
	tl := newTally(3)
	for _, i := range []uint64{0, 1, 1, 7, 2, 0} {
		tl.add(i, time.Millisecond)
	}
	if tl.distinct != 3 || tl.duplicates != 2 || tl.foreign != 1 || !tl.complete() {
		t.Fatalf("distinct=%d duplicates=%d foreign=%d complete=%v", tl.distinct, tl.duplicates, tl.foreign, tl.complete())
	}
	if len(tl.latencies) != 3 {
		t.Fatalf("%d latencies kept, want one per distinct index", len(tl.latencies))
	}
}

func TestPercentileNearestRank(t *testing.T) {
	var d []time.Duration
	for i := 100; i >= 1; i-- {
		d = append(d, time.Duration(i)*time.Millisecond)
	}
	cases := []struct{ q, want float64 }{{50, 50}, {99, 99}, {100, 100}, {0, 1}, {1, 1}}
	for _, c := range cases {
		got, err := percentile(d, c.q)
		if err != nil || got != c.want {
			t.Errorf("p%v = %v (%v), want %v", c.q, got, err, c.want)
		}
	}
	if _, err := percentile(nil, 50); err == nil {
		t.Error("percentile of nothing gave no error")
	}
	if _, err := percentile(d, 101); err == nil {
		t.Error("p101 gave no error")
	}
}

func TestLatencySummaryEmptyIsNull(t *testing.T) {
	s := latencySummary(nil)
	if s["latency_p99_ms"] != nil {
		t.Fatalf("empty summary p99 = %v, want nil", s["latency_p99_ms"])
	}
}
