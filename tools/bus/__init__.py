"""The bus: python-can transports (virtual, udp_multicast, socketcan), the private network
namespace that makes udp_multicast safe, and bus-load arithmetic."""
