// stewart_gym line protocol for an Arduino Uno/Nano + PCA9685 servo board + 4-wire resistive touch panel.
//
// Host → board:  "W w0,w1,w2,w3,w4,w5\n"   six pulse widths in µs for servos 0…5 (PCA9685 channels 0…5)
//                "?\n"                      which pulses are the servos held at now?
// Board → host:  "ready\n"                  once after reset (opening the port resets an Uno through DTR)
//                "P w0,w1,w2,w3,w4,w5\n"   the answer to "?": the pulses last written (µs); deploy asks a few
//                                           times a second (a board that stops answering is a device failure)
//                                           and at the end, to confirm that the servos were sent home
//                "B x,y\n"                  ball position in mm, plate frame, at ~100 Hz ("B -" when not touched)
//                "E <message>\n"            a rejected line
//
// Needs the "Adafruit PWM Servo Driver Library" (Library Manager). Serial: 115200 baud.
// The host's safety layer already keeps every pulse inside the calibrated limits; the limits
// below are a second, independent fence: a frame with any pulse outside them is rejected whole.
#include <Wire.h>
#include <Adafruit_PWMServoDriver.h>

Adafruit_PWMServoDriver pwm = Adafruit_PWMServoDriver(0x40);

const int SERVO_MIN_US = 900;    // hard fence, µs (the host calibration is narrower: 1100…1900 by default)
const int SERVO_MAX_US = 2100;
const int HOME_US[6] = {1500, 1500, 1500, 1500, 1500, 1500};
int heldUs[6] = {1500, 1500, 1500, 1500, 1500, 1500};  // what the servos were last sent

// 4-wire resistive panel: X+ X- Y+ Y- on analog-capable pins.
const int XP = A0, XM = A1, YP = A2, YM = A3;
// Raw ADC → mm (plate frame, origin at the plate centre). Calibrate: touch two known points per axis.
const float X_MM_PER_COUNT = 0.345, X_OFFSET_COUNTS = 512;
const float Y_MM_PER_COUNT = 0.345, Y_OFFSET_COUNTS = 512;
const int TOUCH_MIN_COUNTS = 40;  // below this the panel is not pressed
const unsigned long PANEL_PERIOD_US = 10000;  // 100 Hz

char line[64];
byte lineLen = 0;
unsigned long lastPanel = 0;

void writeServos(const int us[6]) {
  for (int i = 0; i < 6; i++) {
    pwm.writeMicroseconds(i, us[i]);
    heldUs[i] = us[i];
  }
}

void reportHeld() {
  Serial.print("P ");
  for (int i = 0; i < 6; i++) {
    Serial.print(heldUs[i]);
    Serial.print(i < 5 ? "," : "\n");
  }
}

int readAxis(int drivePlus, int driveMinus, int sense, int float_) {
  pinMode(float_, INPUT);
  pinMode(sense, INPUT);
  pinMode(drivePlus, OUTPUT);
  pinMode(driveMinus, OUTPUT);
  digitalWrite(drivePlus, HIGH);
  digitalWrite(driveMinus, LOW);
  delayMicroseconds(50);
  return analogRead(sense);
}

void reportPanel() {
  int x = readAxis(XP, XM, YP, YM);
  int y = readAxis(YP, YM, XP, XM);
  if (x < TOUCH_MIN_COUNTS || y < TOUCH_MIN_COUNTS) {
    Serial.println("B -");
    return;
  }
  Serial.print("B ");
  Serial.print((x - X_OFFSET_COUNTS) * X_MM_PER_COUNT, 1);
  Serial.print(",");
  Serial.println((y - Y_OFFSET_COUNTS) * Y_MM_PER_COUNT, 1);
}

void handleLine() {
  line[lineLen] = 0;
  if (line[0] == '?' && line[1] == 0) {
    reportHeld();
    return;
  }
  if (line[0] != 'W' || line[1] != ' ') {
    Serial.println("E expected W w0,...,w5");
    return;
  }
  int us[6];
  char *p = line + 2;
  for (int i = 0; i < 6; i++) {
    char *end;
    long v = strtol(p, &end, 10);
    if (end == p || v < SERVO_MIN_US || v > SERVO_MAX_US) {
      Serial.println("E pulse missing or outside the fence");
      return;
    }
    us[i] = (int)v;
    p = (*end == ',') ? end + 1 : end;
  }
  writeServos(us);
}

void setup() {
  Serial.begin(115200);
  pwm.begin();
  pwm.setOscillatorFrequency(25000000);
  pwm.setPWMFreq(50);  // one servo frame per 20 ms; 12-bit ticks of 4.88 µs
  writeServos(HOME_US);
  Serial.println("ready");
}

void loop() {
  while (Serial.available()) {
    char c = Serial.read();
    if (c == '\n') {
      handleLine();
      lineLen = 0;
    } else if (c != '\r' && lineLen < sizeof(line) - 1) {
      line[lineLen++] = c;
    }
  }
  unsigned long now = micros();
  if (now - lastPanel >= PANEL_PERIOD_US) {
    lastPanel = now;
    reportPanel();
  }
}
