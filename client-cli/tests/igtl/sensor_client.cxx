// An OpenIGTLink peer built on the reference C++ library (libOpenIGTLink),
// for client-cli/tests/cli/igtl_peers.rs: sends N TRANSFORMs to the bridge and,
// after each, reads messages until the two SENSOR answers of that pose are
// in. Every body is unpacked by the library with its CRC checked
// (Unpack(1)); the SENSOR units are compared with units packed by the
// library's igtl::Unit. Prints one line of key=value counts.
//
// Usage: sensor_client HOST PORT N DEVICE
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "igtlClientSocket.h"
#include "igtlMessageHeader.h"
#include "igtlPolyDataMessage.h"
#include "igtlSensorMessage.h"
#include "igtlStatusMessage.h"
#include "igtlTransformMessage.h"
#include "igtl_unit.h"

int main(int argc, char* argv[])
{
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s HOST PORT N DEVICE\n", argv[0]);
    return 2;
  }
  const int n = std::atoi(argv[3]);
  igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
  if (socket->ConnectToServer(argv[1], std::atoi(argv[2])) != 0) {
    std::fprintf(stderr, "cannot connect\n");
    return 1;
  }
  // Reference units packed by the library's C API (igtl_unit_pack). The C++
  // igtl::Unit of libOpenIGTLink 1.11 keeps only the last unit appended
  // (N m packs as m), so it is not used here.
  igtl_unit_data un;
  igtl_unit_init(&un);
  un.unit[0] = IGTL_UNIT_SI_DERIVED_NEWTON;
  un.exp[0] = 1;
  igtl_unit_data unm = un;
  unm.unit[1] = IGTL_UNIT_SI_BASE_METER;
  unm.exp[1] = 1;
  const igtl_unit newton = igtl_unit_pack(&un);
  const igtl_unit newton_meter = igtl_unit_pack(&unm);

  int sensors = 0, crc_failures = 0, unit_mismatches = 0, statuses = 0;
  int polydata = 0, polydata_points = 0, polydata_polygons_first = -1, others = 0;
  int timestamp_mismatches = 0;
  double last_force_z = 0.0;
  igtl::TransformMessage::Pointer tm = igtl::TransformMessage::New();
  tm->SetDeviceName(argv[4]);
  igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  for (int i = 1; i <= n; i++) {
    igtl::Matrix4x4 m;
    igtl::IdentityMatrix(m);
    // 200 mm above the origin, moving 0.01 mm a pose.
    m[0][3] = 0.01f * i;
    m[2][3] = 200.0f;
    tm->SetMatrix(m);
    ts->SetTime(1000u + i / 1000u, (i % 1000u) * 1000000u);
    tm->SetTimeStamp(ts);
    tm->Pack();
    socket->Send(tm->GetPackPointer(), tm->GetPackSize());
    int answers = 0;
    while (answers < 2) {
      header->InitPack();
      int r = socket->Receive(header->GetPackPointer(), header->GetPackSize());
      if (r != header->GetPackSize()) {
        std::fprintf(stderr, "the bridge closed the connection after %d poses\n", i - 1);
        return 1;
      }
      header->Unpack();
      const std::string type = header->GetDeviceType();
      if (type == "SENSOR") {
        igtl::SensorMessage::Pointer s = igtl::SensorMessage::New();
        s->SetMessageHeader(header);
        s->AllocatePack();
        socket->Receive(s->GetPackBodyPointer(), s->GetPackBodySize());
        if (!(s->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
          crc_failures++;
          answers++;
          continue;
        }
        const std::string dev = s->GetDeviceName();
        const bool force = dev.size() > 6 && dev.compare(dev.size() - 6, 6, "_force") == 0;
        const igtl_unit want = force ? newton : newton_meter;
        if (s->GetUnit() != want || s->GetLength() != 3) unit_mismatches++;
        if (force) last_force_z = s->GetValue(2);
        // The header's 32.32 timestamp, bit for bit (the library's
        // nanosecond conversion alone moves it by up to 3 ns).
        unsigned int sent_sec, sent_frac, got_sec, got_frac;
        tm->GetTimeStamp(&sent_sec, &sent_frac);
        s->GetTimeStamp(&got_sec, &got_frac);
        if (sent_sec != got_sec || sent_frac != got_frac) timestamp_mismatches++;
        sensors++;
        answers++;
      } else if (type == "STATUS") {
        igtl::StatusMessage::Pointer s = igtl::StatusMessage::New();
        s->SetMessageHeader(header);
        s->AllocatePack();
        socket->Receive(s->GetPackBodyPointer(), s->GetPackBodySize());
        if (!(s->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) crc_failures++;
        std::fprintf(stderr, "STATUS %d %s: %s\n", s->GetCode(), s->GetErrorName(), s->GetStatusString());
        statuses++;
      } else if (type == "POLYDATA") {
        igtl::PolyDataMessage::Pointer p = igtl::PolyDataMessage::New();
        p->SetMessageHeader(header);
        p->AllocatePack();
        socket->Receive(p->GetPackBodyPointer(), p->GetPackBodySize());
        if (!(p->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
          crc_failures++;
          continue;
        }
        polydata_points = p->GetPoints() ? p->GetPoints()->GetNumberOfPoints() : 0;
        if (polydata == 0) {
          polydata_polygons_first = p->GetPolygons() ? (int)p->GetPolygons()->GetNumberOfCells() : 0;
        }
        polydata++;
      } else {
        socket->Skip(header->GetBodySizeToRead(), 0);
        others++;
      }
    }
  }
  socket->CloseSocket();
  std::printf(
      "sensors=%d crc_failures=%d unit_mismatches=%d timestamp_mismatches=%d statuses=%d "
      "polydata=%d polydata_points=%d polydata_polygons_first=%d others=%d last_force_z=%g\n",
      sensors, crc_failures, unit_mismatches, timestamp_mismatches, statuses, polydata,
      polydata_points, polydata_polygons_first, others, last_force_z);
  return 0;
}
