// Runs the stewart_gym sketch on the host (tests/hardware/test_sketch.py): commands on stdin, what the board
// sends on stdout, each I2C write as a line "#I2C <address> <register> <bytes>" (hex).
//   send TEXT    the host sends TEXT and a newline;      raw TEXT   the host sends TEXT alone
//   touch X Y    the ball presses the panel where the X and Y layers read X and Y counts;   untouch
//   loop N       N passes of loop(), 1 ms apart
//   brownout     the PCA9685 resets (its power dipped): asleep, its prescale lost
//   nack         the PCA9685 does not acknowledge the next write of several bytes (a bus error)
// Started with the argument "nopca", no PCA9685 answers; the harness stops after the sketch's third wait.
#include <cstdlib>
#include <cstring>
#include <deque>
#include <iostream>
#include <string>
#include <vector>

#include "Arduino.h"
#include "Wire.h"

HostSerial Serial;
TwoWire Wire;

static unsigned long now_us = 0;
static std::deque<char> incoming;
static bool pca_present = true, touched = false;
static int touch_x = 512, touch_y = 512, delays = 0;
static int mode[32], level[32];
static std::vector<uint8_t> transaction;
static long i2c_clock = 100000;
static uint8_t regs[256], pointer = 0;  // the PCA9685's registers, and the one a read starts at
static bool nack_next = false;

void pinMode(int pin, int m) { mode[pin] = m; }
void digitalWrite(int pin, int v) { level[pin] = v; }
void delayMicroseconds(unsigned int us) { now_us += us; }
void delay(unsigned long ms) {
  now_us += ms * 1000;
  if (++delays >= 3 && !pca_present) {
    std::fflush(stdout);
    std::exit(0);
  }
}
unsigned long micros() { return now_us; }
int HostSerial::available() { return (int)incoming.size(); }
int HostSerial::read() {
  if (incoming.empty()) return -1;
  char c = incoming.front();
  incoming.pop_front();
  return (unsigned char)c;
}

static bool driven(int pin, int v) { return mode[pin] == OUTPUT && level[pin] == v; }

// A 4-wire panel: pressed, the layers meet; the touch test (Y+ pulled up, X- low) reads low, a driven layer
// gives the other layer's pin its voltage at the ball. Untouched, a sense pin floats: it reads mid-scale.
int analogRead(int pin) {
  if (pin == A2 && mode[A2] == INPUT_PULLUP && driven(A1, LOW)) return touched ? 200 : 1023;
  if (pin == A2 && driven(A0, HIGH) && driven(A1, LOW) && mode[A2] == INPUT) return touched ? touch_x : 512;
  if (pin == A0 && driven(A2, HIGH) && driven(A3, LOW) && mode[A0] == INPUT) return touched ? touch_y : 512;
  std::printf("#BADREAD pin %d\n", pin);
  return 0;
}

void TwoWire::setClock(long hz) { i2c_clock = hz; }
void TwoWire::beginTransmission(uint8_t address) { transaction.assign(1, address); }
void TwoWire::write(uint8_t value) { transaction.push_back(value); }
uint8_t TwoWire::endTransmission() {  // transaction: the address, the register, then the data
  if (!pca_present) return 2;  // address not acknowledged
  if (transaction.size() > 2 && nack_next) {
    nack_next = false;
    std::printf("#NACK\n");
    return 3;  // data not acknowledged
  }
  if (transaction.size() > 2) {
    std::printf("#I2C");
    for (uint8_t b : transaction) std::printf(" %02x", b);
    std::printf("\n");
  }
  if (transaction.size() > 1) pointer = transaction[1];
  for (size_t k = 2; k < transaction.size(); k++) regs[pointer++] = transaction[k];  // (auto-increment)
  if (transaction.size() > 1) pointer = transaction[1];
  return 0;
}
uint8_t TwoWire::requestFrom(uint8_t, uint8_t count) { return pca_present ? count : 0; }
int TwoWire::read() { return regs[pointer++]; }

#include SKETCH

int main(int argc, char **argv) {
  pca_present = !(argc > 1 && std::strcmp(argv[1], "nopca") == 0);
  regs[0x00] = 0x11;  // MODE1 at power-up: asleep
  regs[0xFE] = 0x1E;
  setup();
  std::printf("#CLOCK %ld\n", i2c_clock);
  std::string line;
  while (std::getline(std::cin, line)) {
    if (line.rfind("send ", 0) == 0 || line.rfind("raw ", 0) == 0) {
      bool send = line[0] == 's';
      std::string text = line.substr(send ? 5 : 4);
      for (char c : text) incoming.push_back(c);
      if (send) incoming.push_back('\n');
    } else if (line.rfind("touch ", 0) == 0) {
      touched = true;
      std::sscanf(line.c_str() + 6, "%d %d", &touch_x, &touch_y);
    } else if (line == "untouch") {
      touched = false;
    } else if (line == "brownout") {
      regs[0x00] = 0x11;  // MODE1 at power-up: asleep, all-call
      regs[0xFE] = 0x1E;  // PRE_SCALE at power-up: 200 Hz
    } else if (line == "nack") {
      nack_next = true;
    } else if (line.rfind("loop ", 0) == 0) {
      for (int k = std::atoi(line.c_str() + 5); k > 0; k--) {
        loop();
        now_us += 1000;
      }
    }
  }
  return 0;
}
