package main

// Options shared by every mode: TLS, the password (file or environment, never argv), the
// deadline, and the one-line JSON report with the process's own CPU time.

import (
	"crypto/tls"
	"crypto/x509"
	"encoding/json"
	"errors"
	"flag"
	"fmt"
	"os"
	"strings"
	"syscall"
	"time"
)

// passwordEnv is where a password comes from when no --password-file is given.
const passwordEnv = "LOADGEN_PASSWORD"

type common struct {
	topic        string
	count        uint64
	deadline     time.Duration
	caFile       string
	noVerify     bool
	username     string
	passwordFile string
}

func (c *common) register(fs *flag.FlagSet) {
	fs.StringVar(&c.topic, "topic", "", "topic to publish to or read (required)")
	fs.Uint64Var(&c.count, "n", 1000, "number of messages")
	fs.DurationVar(&c.deadline, "deadline", 120*time.Second, "give up after this long")
	fs.StringVar(&c.caFile, "ca-file", "", "speak TLS, verifying the server against this CA (PEM)")
	fs.BoolVar(&c.noVerify, "no-verify", false, "speak TLS without verifying the server certificate")
	fs.StringVar(&c.username, "username", "", "log in as this user (password from --password-file or $"+passwordEnv+")")
	fs.StringVar(&c.passwordFile, "password-file", "", "file holding the password (first line)")
}

func (c *common) validate() error {
	if c.topic == "" {
		return errors.New("--topic is required")
	}
	if c.count == 0 {
		return errors.New("--n must be at least 1")
	}
	if c.deadline <= 0 {
		return errors.New("--deadline must be positive")
	}
	return nil
}

func (c *common) tlsWanted() bool { return c.caFile != "" || c.noVerify }

// tlsConfig is nil for plain connections; the server name is the host the client dials.
func (c *common) tlsConfig(host string) (*tls.Config, error) {
	if !c.tlsWanted() {
		return nil, nil
	}
	cfg := &tls.Config{ServerName: host, MinVersion: tls.VersionTLS12}
	if c.noVerify {
		cfg.InsecureSkipVerify = true
		return cfg, nil
	}
	pem, err := os.ReadFile(c.caFile)
	if err != nil {
		return nil, fmt.Errorf("--ca-file: %w", err)
	}
	pool := x509.NewCertPool()
	if !pool.AppendCertsFromPEM(pem) {
		return nil, fmt.Errorf("--ca-file %s holds no PEM certificate", c.caFile)
	}
	cfg.RootCAs = pool
	return cfg, nil
}

// password reads --password-file or $LOADGEN_PASSWORD; "" when neither is set.
func (c *common) password() (string, error) {
	if c.passwordFile != "" {
		raw, err := os.ReadFile(c.passwordFile)
		if err != nil {
			return "", fmt.Errorf("--password-file: %w", err)
		}
		line, _, _ := strings.Cut(string(raw), "\n")
		return strings.TrimRight(line, "\r"), nil
	}
	return os.Getenv(passwordEnv), nil
}

// cpuSeconds is the user and system CPU this process has used so far.
func cpuSeconds() (float64, float64) {
	var ru syscall.Rusage
	if err := syscall.Getrusage(syscall.RUSAGE_SELF, &ru); err != nil {
		return 0, 0
	}
	sec := func(tv syscall.Timeval) float64 { return float64(tv.Sec) + float64(tv.Usec)/1e6 }
	return sec(ru.Utime), sec(ru.Stime)
}

// emit prints one JSON line on stdout; the Python wrapper reads every line as an event.
func emit(fields map[string]any) {
	line, err := json.Marshal(fields)
	if err != nil {
		fmt.Fprintf(os.Stderr, "loadgen: cannot encode report: %v\n", err)
		os.Exit(2)
	}
	fmt.Println(string(line))
}

// report adds elapsed, rate and CPU to a mode's fields and prints them.
func report(mode string, fields map[string]any, counted uint64, elapsed time.Duration) {
	user, sys := cpuSeconds()
	fields["mode"] = mode
	fields["elapsed_s"] = elapsed.Seconds()
	rate := 0.0
	if elapsed > 0 {
		rate = float64(counted) / elapsed.Seconds()
	}
	fields["rate_per_s"] = rate
	fields["cpu_user_s"] = user
	fields["cpu_sys_s"] = sys
	emit(fields)
}
