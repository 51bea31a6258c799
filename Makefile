# Convenience targets; the scripts do the work (a fresh machine needs only bash and python3).
.PHONY: demo test bags bench
demo:
	bash scripts/demo.sh
test:
	bash scripts/test.sh
bags:
	bash scripts/make_sample_bags.sh
bench:
	bash scripts/venv.sh && for b in benchmarks/bench_*.py; do .venv/bin/python $$b; done
