"""The cluster test harness: racer's roles across real processes, containers and network links, run from a checkout.

``check-compose.sh`` and ``check-swarm.sh`` (with ``docker-test-lib.sh``, the test overrides ``compose.test.yml``,
``swarm.test.yml``, ``compose.test.hyperparameters.json`` and the image stand-ins in ``standins/``) run
docker-compose.yml for real; ``check-hosts.sh`` runs workers on other hosts over a shaped, lossy, cut network in Linux
namespaces, with ``delay_proxy`` for the latency and ``hosts_probe`` for the measurements and checks. None of it is
part of the wheel or the image.
"""
