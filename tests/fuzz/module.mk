# tests/fuzz/module.mk - libFuzzer targets for the parsers a user's file reaches (docs/reliability.md;
# included by the top-level Makefile).
#   make fuzz FUZZ_S=N   build every target with clang (-fsanitize=fuzzer,address,undefined and
#                        the clang pass's extra checks) into build/fuzz/, then run each N seconds
#                        (default 60) from its seeds (tests/fuzz/corpus/NAME/) under -rss_limit_mb=2048
#                        and -timeout=10, scratch files in /dev/shm (12x the executions of
#                        a disk-backed /tmp); new inputs in build/fuzz/corpus/NAME/, crashes in
#                        build/fuzz/crash-NAME-* (copy them to tests/fuzz/crashes/NAME/: make check
#                        replays those, tests/test_fuzz_replay.c)
#   make fuzz FUZZ_RUNS=N  each target for N executions instead (-runs=N; the campaign of
#                        docs/reliability.md: FUZZ_RUNS=1000000), stopped after FUZZ_S seconds
#                        only if FUZZ_S is given too
#   FUZZ_NAMES="a b"     only these targets, in this order (default: every tests/fuzz/fuzz_*.c)
FUZZ_S ?= 60
FUZZ_RUNS ?=
FUZZ_NAMES := $(patsubst tests/fuzz/fuzz_%.c,%,$(wildcard tests/fuzz/fuzz_*.c))
FUZZ_BINS := $(foreach n,$(FUZZ_NAMES),$(BUILD)/tests/fuzz/fuzz_$(n))

.PHONY: fuzz fuzz-run
fuzz: deps
	$(MAKE) --no-print-directory BUILD=build/fuzz SAN=fuzz fuzz-run
ifeq ($(SAN),fuzz)
.SECONDARY: $(FUZZ_BINS:=.o)
# (the targets that reach survey/ link capture/ and with it the binary's libgpiod)
$(BUILD)/tests/fuzz/fuzz_%: $(BUILD)/tests/fuzz/fuzz_%.o $(LIBS)
	$(CXX) -fsanitize=fuzzer $(LDFLAGS) $^ $(LDLIBS) -lgpiod -o $@
fuzz-run: $(FUZZ_BINS)
	@scratch=$$(mktemp -d "$$( [ -d /dev/shm ] && echo /dev/shm || echo "$${TMPDIR:-/tmp}" )/gridsurvey-fuzz.XXXXXX"); \
	for n in $(FUZZ_NAMES); do \
	  mkdir -p $(BUILD)/corpus/$$n; \
	  echo "fuzz $$n: $(if $(FUZZ_RUNS),$(FUZZ_RUNS) executions,$(FUZZ_S) s)"; t0=$$(date +%s); \
	  TMPDIR=$$scratch $(BUILD)/tests/fuzz/fuzz_$$n \
	    $(if $(FUZZ_RUNS),-runs=$(FUZZ_RUNS) $(if $(filter command line,$(origin FUZZ_S)),-max_total_time=$(FUZZ_S)),-max_total_time=$(FUZZ_S)) -rss_limit_mb=2048 -timeout=10 \
	    -print_final_stats=1 -artifact_prefix=$(BUILD)/crash-$$n- \
	    $$( [ -f tests/fuzz/dict/$$n.dict ] && echo -dict=tests/fuzz/dict/$$n.dict ) \
	    $(BUILD)/corpus/$$n tests/fuzz/corpus/$$n > $(BUILD)/fuzz-$$n.log 2>&1; rc=$$?; \
	  grep -E '^stat::number_of_executed_units|^stat::peak_rss_mb|ERROR|SUMMARY' $(BUILD)/fuzz-$$n.log; \
	  echo "fuzz $$n: $$(( $$(date +%s) - t0 )) s wall, exit $$rc"; \
	  [ $$rc -eq 0 ] || { echo "fuzz $$n: FAILED (exit $$rc, $(BUILD)/fuzz-$$n.log)"; failed=1; }; \
	done; rm -rf "$$scratch"; [ -z "$$failed" ]
endif
