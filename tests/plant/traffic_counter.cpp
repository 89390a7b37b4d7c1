// Counts the RTPS datagrams that a set of network interfaces carry, split into
// discovery (Fast DDS's builtin "metatraffic": participant announcements, endpoint
// discovery, liveliness, and everything to or from a Discovery Server) and user data,
// by UDP destination port. Used by tests/plant/discovery_server_test.sh on the host
// ends of the veth pairs that join the test's network namespaces to its bridge.
//
//   ve_plant_traffic --domain D --server-ports P[,P...] --ifaces IF[,IF...]
//
// Each frame is counted once, on the interface it entered the bridge from (frames the
// host sends out of an interface are not counted), so a datagram that the bridge floods
// to every port (multicast) counts once, as it was sent.
// RTPS ports of domain D (the RTPS 2.x well-known ports, PB 7400, DG 250, PG 2):
//   7400 + 250 D + 0          discovery, multicast
//   7400 + 250 D + 1          user data, multicast
//   7400 + 250 D + 10 + 2 i   discovery, unicast to participant i
//   7400 + 250 D + 11 + 2 i   user data, unicast to participant i
// and the Discovery Servers' ports (--server-ports) are discovery.
// Anything else (ARP, IPv6, other ports, IP fragments after the first) is "other".
//
// Output: one line on SIGUSR1 (SNAPSHOT, cumulative) and at SIGINT/SIGTERM (END):
//   SNAPSHOT|END seconds=S discovery_packets=N discovery_bytes=B data_packets=N
//                data_bytes=B other_packets=N other_bytes=B
// Bytes are whole Ethernet frames. Needs CAP_NET_RAW (root). Exit 1 when the socket
// cannot be opened or an interface does not exist.
#include <arpa/inet.h>
#include <linux/if_packet.h>
#include <net/ethernet.h>
#include <net/if.h>
#include <netinet/ip.h>
#include <netinet/udp.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace {

volatile sig_atomic_t g_stop = 0;
volatile sig_atomic_t g_snapshot = 0;
void on_stop(int) { g_stop = 1; }
void on_snapshot(int) { g_snapshot = 1; }

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

double now_s() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<double>(ts.tv_sec) + ts.tv_nsec * 1e-9;
}

struct Counts {
  unsigned long long packets[3] = {0, 0, 0};  // discovery, data, other
  unsigned long long bytes[3] = {0, 0, 0};
};

void print(const char* tag, const Counts& c, double seconds) {
  std::printf("%s seconds=%.1f discovery_packets=%llu discovery_bytes=%llu data_packets=%llu data_bytes=%llu "
              "other_packets=%llu other_bytes=%llu\n",
              tag, seconds, c.packets[0], c.bytes[0], c.packets[1], c.bytes[1], c.packets[2], c.bytes[2]);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  int domain = -1;
  std::set<int> server_ports;
  std::set<int> ifindexes;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i], value = argv[i + 1];
    if (key == "--domain") {
      domain = std::atoi(value.c_str());
    } else if (key == "--server-ports") {
      for (const auto& p : split(value)) server_ports.insert(std::atoi(p.c_str()));
    } else if (key == "--ifaces") {
      for (const auto& name : split(value)) {
        const unsigned idx = if_nametoindex(name.c_str());
        if (idx == 0) {
          std::fprintf(stderr, "ve_plant_traffic: no interface '%s'\n", name.c_str());
          return 1;
        }
        ifindexes.insert(static_cast<int>(idx));
      }
    } else {
      std::fprintf(stderr, "ve_plant_traffic: unknown option '%s'\n", key.c_str());
      return 2;
    }
  }
  if (domain < 0 || ifindexes.empty()) {
    std::fprintf(stderr, "usage: ve_plant_traffic --domain D --server-ports P[,P...] --ifaces IF[,IF...]\n");
    return 2;
  }
  const int fd = socket(AF_PACKET, SOCK_RAW, htons(ETH_P_ALL));
  if (fd < 0) {
    std::fprintf(stderr, "ve_plant_traffic: AF_PACKET socket: %s\n", std::strerror(errno));
    return 1;
  }
  int rcvbuf = 8 << 20;
  setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &rcvbuf, sizeof rcvbuf);
  struct sigaction sa {};
  sa.sa_handler = on_stop;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  sa.sa_handler = on_snapshot;
  sigaction(SIGUSR1, &sa, nullptr);

  const int base = 7400 + 250 * domain;
  Counts c;
  const double t0 = now_s();
  std::printf("READY\n");
  std::fflush(stdout);
  std::vector<unsigned char> buf(65536);
  while (!g_stop) {
    if (g_snapshot) {
      g_snapshot = 0;
      print("SNAPSHOT", c, now_s() - t0);
    }
    pollfd p{fd, POLLIN, 0};
    const int r = poll(&p, 1, 100);
    if (r <= 0) continue;
    sockaddr_ll from{};
    socklen_t from_len = sizeof from;
    const ssize_t n = recvfrom(fd, buf.data(), buf.size(), MSG_TRUNC, reinterpret_cast<sockaddr*>(&from), &from_len);
    if (n <= 0) continue;
    if (from.sll_pkttype == PACKET_OUTGOING || ifindexes.count(from.sll_ifindex) == 0) continue;
    int kind = 2;
    const std::size_t len = static_cast<std::size_t>(n);
    if (len >= sizeof(ether_header) + sizeof(iphdr) &&
        ntohs(reinterpret_cast<const ether_header*>(buf.data())->ether_type) == ETHERTYPE_IP) {
      const auto* ip = reinterpret_cast<const iphdr*>(buf.data() + sizeof(ether_header));
      const std::size_t ihl = ip->ihl * 4u;
      const bool first_fragment = (ntohs(ip->frag_off) & IP_OFFMASK) == 0;
      if (ip->protocol == IPPROTO_UDP && first_fragment && len >= sizeof(ether_header) + ihl + sizeof(udphdr)) {
        const auto* udp = reinterpret_cast<const udphdr*>(buf.data() + sizeof(ether_header) + ihl);
        const int port = ntohs(udp->dest);
        const int off = port - base;
        if (server_ports.count(port) > 0 || off == 0 || (off >= 10 && off < 250 && off % 2 == 0))
          kind = 0;
        else if (off == 1 || (off >= 11 && off < 250 && off % 2 == 1))
          kind = 1;
      }
    }
    c.packets[kind] += 1;
    c.bytes[kind] += len;
  }
  print("END", c, now_s() - t0);
  close(fd);
  return 0;
}
