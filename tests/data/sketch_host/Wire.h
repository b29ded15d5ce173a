// Arduino's Wire (I2C), as much as the sketch uses, for the host tests: each transaction is printed by the harness.
#pragma once
#include <cstdint>

class TwoWire {
 public:
  void begin() {}
  void setClock(long hz);
  void setWireTimeout(unsigned long, bool) {}
  void beginTransmission(uint8_t address);
  void write(uint8_t value);
  uint8_t endTransmission();
  uint8_t requestFrom(uint8_t address, uint8_t count);
  int read();
};
extern TwoWire Wire;
