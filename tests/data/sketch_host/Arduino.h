// The Arduino core, as much of it as the stewart_gym sketch uses, for compiling it on the host in the tests
// (tests/hardware/test_sketch.py): pins, time and Serial are the harness's (harness.cpp).
#pragma once
#include <cstdint>
#include <cstdio>
#include <string>

typedef uint8_t byte;
enum { INPUT = 0, OUTPUT = 1, INPUT_PULLUP = 2, LOW = 0, HIGH = 1 };
enum { A0 = 14, A1 = 15, A2 = 16, A3 = 17 };

void pinMode(int pin, int mode);
void digitalWrite(int pin, int value);
int analogRead(int pin);
void delayMicroseconds(unsigned int us);
void delay(unsigned long ms);
unsigned long micros();

class HostSerial {
 public:
  void begin(long) {}
  int available();
  int read();
  void print(const char *s) { out(s); }
  void print(char c) { out(std::string(1, c)); }
  void print(int v) { out(std::to_string(v)); }
  void print(long v) { out(std::to_string(v)); }
  void print(unsigned int v) { out(std::to_string(v)); }
  void print(double v, int digits = 2) {
    char text[64];
    std::snprintf(text, sizeof(text), "%.*f", digits, v);
    out(text);
  }
  template <typename T> void println(T v) { print(v); out("\r\n"); }
  void println(double v, int digits) { print(v, digits); out("\r\n"); }
 private:
  void out(const std::string &s) { std::fputs(s.c_str(), stdout); }
};
extern HostSerial Serial;
