# Convenience targets; the scripts do the work (a fresh machine needs only bash and python3).
.PHONY: demo test lint bags bench
demo:
	bash scripts/demo.sh
test:
	bash scripts/test.sh
lint:
	bash scripts/lint.sh
bags:
	bash scripts/make_sample_bags.sh
bench:
	bash scripts/venv.sh && for b in benchmarks/bench_*.py; do .venv/bin/python $$b; done
