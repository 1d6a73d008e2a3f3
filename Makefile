# LaserPi: `make demo` runs the simulated sensor end to end; `make test` runs every test.
# Both install what they need first (tools/bootstrap.sh).
PY := .venv/bin/python

.PHONY: demo test firmware bootstrap clean

bootstrap:
	@./tools/bootstrap.sh

firmware: bootstrap
	@$(MAKE) --no-print-directory -C firmware_pwm

demo: firmware
	@$(PY) -m device.cli demo

test: firmware
	@$(PY) -m pytest -q

clean:
	rm -rf .venv firmware_pwm/build .pytest_cache build device/vision/_columns*.so
