#!/usr/bin/env bash
# Runs a command at the lowest CPU priority that holds on a kernel with autogroup scheduling
# (/proc/sys/kernel/sched_autogroup_enabled = 1, as on our VMs): there, `nice` only orders the
# processes of one session against each other, and each session's group gets an equal share of
# the CPU whatever its processes' nice values. So a `nice -n 19` render started from another shell
# took half the machine from a training run (seen 2026-12-07 with top: the render at 106% of a
# core, two one-thread trainings at 37% each; after `echo 19 > /proc/<pid>/autogroup`, 6% and 100% each).
# The command gets its own session, whose group is set to nice 19 as well as the process.
# Usage: docs/nice19.sh CMD [ARG...]   (exit status and signals are CMD's: setsid execs in place
# when the caller is not a process-group leader, as in scripts and under timeout)
exec setsid --wait bash -c 'echo 19 > /proc/self/autogroup 2>/dev/null || true; exec nice -n 19 "$@"' nice19 "$@"
