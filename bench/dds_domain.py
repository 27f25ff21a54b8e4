"""The DDS participants on a ROS domain on this host, read from the UDP ports they listen on.

RTPS (spec 9.6.1.1, Fast DDS's defaults) puts the discovery (metatraffic unicast) port of
participant ``p`` of domain ``d`` at ``7400 + 250 d + 10 + 2 p``; each rclpy ``Context`` with
a node is one participant. With ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` rmw_fastrtps
announces a new participant only to participants 0..31 (``maxInitialPeersRange = 32``):
two participants that both get an id of 32 or more never discover each other. So a domain
whose ids 0..31 are all taken cannot host a live run: the node and the player never match.
Seen once in CI (2026-12-03: two live==offline tests waited 180 s for a match, nothing
else failed) and reproduced here with 32 idle contexts on the test's domain (the same
test, the same 180-s wait).

Linux only (``/proc/net/udp``, ``/proc/net/udp6``); elsewhere ``participants`` returns None.
Pure standard library, no rclpy: the test configuration uses it before rclpy is loaded.
"""

#: RTPS port parameters (spec 9.6.1.1): port base, domain gain, participant gain, d1
PORT_BASE, DOMAIN_GAIN, PARTICIPANT_GAIN, D1 = 7400, 250, 2, 10
#: participants rmw_fastrtps reaches on localhost (its UDP maxInitialPeersRange)
LOCALHOST_PEERS = 32
#: participant ids whose port stays inside the domain's 250 ports
MAX_PARTICIPANTS = (DOMAIN_GAIN - D1) // PARTICIPANT_GAIN
#: the domains ROS recommends on Linux (above 101 the ports reach the ephemeral range)
DOMAINS = range(1, 102)
_TABLES = ('/proc/net/udp', '/proc/net/udp6')


def _bound_ports():
    """Return the local UDP ports bound on this host (its network namespace), or None."""
    ports = set()
    read = False
    for table in _TABLES:
        try:
            with open(table) as f:
                lines = f.read().splitlines()[1:]
        except OSError:
            continue
        read = True
        for line in lines:
            fields = line.split()
            if len(fields) > 1 and ':' in fields[1]:
                ports.add(int(fields[1].rsplit(':', 1)[1], 16))
    return ports if read else None


def participants(domain_id, ports=None):
    """Return the sorted participant ids with a discovery port bound on ``domain_id``.

    None when the UDP tables cannot be read (not Linux). ``ports``: the bound ports, when
    already read (``free_domain`` reads them once).
    """
    ports = _bound_ports() if ports is None else ports
    if ports is None:
        return None
    first = PORT_BASE + DOMAIN_GAIN * int(domain_id) + D1
    return sorted((p - first) // PARTICIPANT_GAIN for p in ports
                  if first <= p < first + PARTICIPANT_GAIN * MAX_PARTICIPANTS
                  and (p - first) % PARTICIPANT_GAIN == 0)


def saturated(ids):
    """Return True when ids 0..31 are all taken: two new participants would not match."""
    return ids is not None and set(range(LOCALHOST_PEERS)) <= set(ids)


def free_domain(candidates):
    """Return the first of ``candidates`` with no participant on it (this host), else None.

    Without the UDP tables (not Linux) the first candidate is returned.
    """
    candidates = list(candidates)
    ports = _bound_ports()
    if ports is None:
        return candidates[0] if candidates else None
    return next((d for d in candidates if not participants(d, ports)), None)


def worker_domains(base, worker, workers):
    """Return the domains worker ``worker`` of ``workers`` may take, starting near ``base``.

    Worker k takes base + k, base + k + workers, ... (wrapping inside ``DOMAINS``): two
    workers choosing at the same moment never pick the same domain.
    """
    n = len(DOMAINS)
    return [DOMAINS[(base - DOMAINS[0] + worker + workers * j) % n]
            for j in range(n // workers)]


def describe(domain_id):
    """Return a sentence on the participants bound on ``domain_id``, for a failure message."""
    ids = participants(domain_id)
    if ids is None:
        return f'the DDS participants on domain {domain_id} are unknown (no /proc/net/udp)'
    text = f'{len(ids)} DDS participant(s) bound on domain {domain_id} on this host'
    if saturated(ids):
        text += (f' (ids 0..{LOCALHOST_PEERS - 1} all taken: with '
                 f'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST Fast DDS announces a new participant '
                 f'only to those, so two new ones never match; stop the processes on the '
                 f'domain or choose another, ROS_DOMAIN_ID=N)')
    return text
