// stewart_gym line protocol for an Arduino Uno/Nano + PCA9685 servo board + 4-wire resistive touch panel.
//
// Host → board:  "W w0,w1,w2,w3,w4,w5\n"   six pulse widths in µs (whole numbers of 3 or 4 digits, one comma
//                                           between them, nothing else) for servos 0…5 on PCA9685 channels 0…5
//                "?\n"                      which pulses are the servos held at now?
// Board → host:  "ready 900,2100\n"         once after reset (opening the port resets an Uno through DTR), with
//                                           the fence below: the host refuses a calibration that leaves it
//                "P w0,w1,w2,w3,w4,w5\n"   the answer to "?": the pulses last written, as asked (µs); deploy asks
//                                           a few times a second (a board that stops answering is a device
//                                           failure) and at the end, to confirm that the servos were sent home
//                "B x,y\n"                  ball position in mm, plate frame, at 100 Hz ("B -" when not touched)
//                "E <message>\n"            a refused line: nothing moved (the host stops a run that is refused
//                                           3 times in 10 frames: its servos would be frozen)
//
// What the board does on its own:
//  - at reset it sets every servo to HOME_US (1500 µs) at once: neutral, without the calibration's trims;
//  - it holds the last frame it accepted until the next one; if the host goes silent it holds that pose;
//  - a frame with any pulse outside [SERVO_MIN_US, SERVO_MAX_US] is refused whole (a second fence: the host's
//    safety layer already keeps every pulse within the calibrated limits);
//  - without a PCA9685 answering at PCA9685_ADDRESS it says so every second and never says "ready".
//
// Needs only the Arduino core (Wire). Serial: 115200 baud. The PCA9685 is driven through its registers: all six
// channels are written in one I²C transaction at 400 kHz, so they change together.
#include <Wire.h>

const uint8_t PCA9685_ADDRESS = 0x40;  // A0…A5 address jumpers open
// The PCA9685's internal oscillator runs at 23–27 MHz from chip to chip, and every pulse scales with it. Measure
// it: with this sketch running, measure the servo signal's frequency f on any channel (a multimeter's Hz range,
// or a scope); your chip's oscillator is f × 4096 × (PRESCALE + 1), f × 499,712 at the prescale of 121. Set that
// here and flash again.
const long OSCILLATOR_HZ = 25000000L;
const long FRAME_HZ = 50;  // one servo pulse every 20 ms
const uint8_t PRESCALE = (OSCILLATOR_HZ + 4096L * FRAME_HZ / 2) / (4096L * FRAME_HZ) - 1;  // 121 at 25 MHz

const int SERVO_MIN_US = 900;  // hard fence, µs (the host refuses a calibration whose limits leave it)
const int SERVO_MAX_US = 2100;
const int HOME_US = 1500;
int heldUs[6] = {HOME_US, HOME_US, HOME_US, HOME_US, HOME_US, HOME_US};  // what the servos were last sent

// 4-wire resistive panel: X+ X- Y+ Y- on analog-capable pins.
const int XP = A0, XM = A1, YP = A2, YM = A3;
// Raw ADC → mm (plate frame, origin at the plate centre). Calibrate: touch two known points per axis.
const float X_MM_PER_COUNT = 0.345, X_OFFSET_COUNTS = 512;
const float Y_MM_PER_COUNT = 0.345, Y_OFFSET_COUNTS = 512;
// Touch test: Y+ pulled up, X- low. Pressed, the layers meet and pull Y+ down; untouched it reads near 1023.
const int TOUCH_MAX_COUNTS = 800;
const unsigned long PANEL_PERIOD_US = 10000;  // 100 Hz

char line[64];
byte lineLen = 0;
const char *lineFault = 0;  // why the line being read cannot be taken (too long, a NUL in it), or 0
unsigned long lastPanel = 0;

bool pcaAnswers() {
  Wire.beginTransmission(PCA9685_ADDRESS);
  return Wire.endTransmission() == 0;
}

void pcaWrite(uint8_t reg, uint8_t value) {
  Wire.beginTransmission(PCA9685_ADDRESS);
  Wire.write(reg);
  Wire.write(value);
  Wire.endTransmission();
}

uint8_t pcaRead(uint8_t reg) {  // 0x10 (asleep) where it does not answer: set up again, then refused
  Wire.beginTransmission(PCA9685_ADDRESS);
  Wire.write(reg);
  if (Wire.endTransmission() != 0 || Wire.requestFrom(PCA9685_ADDRESS, (uint8_t)1) != 1) {
    return 0x10;
  }
  return Wire.read();
}

void pcaSetup() {
  pcaWrite(0x00, 0x10);      // MODE1: sleep, so that the prescale can be set
  pcaWrite(0xFE, PRESCALE);  // PRE_SCALE
  pcaWrite(0x01, 0x04);      // MODE2: totem-pole outputs
  pcaWrite(0x00, 0x20);      // MODE1: awake, register auto-increment
  delayMicroseconds(500);    // the oscillator starts
}

// µs → PCA9685 ticks of (PRESCALE + 1) / OSCILLATOR_HZ s (4.88 µs at 25 MHz), rounded to the nearest.
unsigned int ticksOf(int us) {
  long perTick = (PRESCALE + 1L) * 1000L;  // µs × OSCILLATOR_HZ / 1000 per tick
  return (unsigned int)(((long)us * (OSCILLATOR_HZ / 1000L) + perTick / 2) / perTick);
}

// The six channels in one transaction; false (nothing held changed) if the PCA9685 did not take it.
bool writeServos(const int us[6]) {
  if (pcaRead(0x00) & 0x10) {  // MODE1 asleep: it was reset (its power dipped) and lost its setup
    Serial.println("E PCA9685 had reset (its power dipped?): set up again");
    pcaSetup();
  }
  Wire.beginTransmission(PCA9685_ADDRESS);
  Wire.write(0x06);  // LED0_ON_L, then 4 bytes a channel (ON low, ON high, OFF low, OFF high) for channels 0…5
  for (int i = 0; i < 6; i++) {
    unsigned int off = ticksOf(us[i]);
    Wire.write(0);
    Wire.write(0);
    Wire.write(off & 0xFF);
    Wire.write(off >> 8);
  }
  if (Wire.endTransmission() != 0) {
    Serial.println("E PCA9685 did not take the frame (I2C error)");
    return false;
  }
  for (int i = 0; i < 6; i++) {
    heldUs[i] = us[i];
  }
  return true;
}

void reportHeld() {
  Serial.print("P ");
  for (int i = 0; i < 6; i++) {
    Serial.print(heldUs[i]);
    Serial.print(i < 5 ? "," : "\n");
  }
}

void releasePanel() {  // no pin driven between readings: no current through the panel
  pinMode(XP, INPUT);
  pinMode(XM, INPUT);
  pinMode(YP, INPUT);
  pinMode(YM, INPUT);
}

bool panelTouched() {
  releasePanel();
  pinMode(XM, OUTPUT);
  digitalWrite(XM, LOW);
  pinMode(YP, INPUT_PULLUP);
  delayMicroseconds(50);
  int z = analogRead(YP);
  releasePanel();
  return z < TOUCH_MAX_COUNTS;
}

int readAxis(int drivePlus, int driveMinus, int sense) {
  releasePanel();
  pinMode(drivePlus, OUTPUT);
  pinMode(driveMinus, OUTPUT);
  digitalWrite(drivePlus, HIGH);
  digitalWrite(driveMinus, LOW);
  delayMicroseconds(50);
  int counts = analogRead(sense);
  releasePanel();
  return counts;
}

void reportPanel() {
  if (!panelTouched()) {
    Serial.println("B -");
    return;
  }
  int x = readAxis(XP, XM, YP);
  int y = readAxis(YP, YM, XP);
  if (!panelTouched()) {  // let go while it was read: the readings are not the ball's
    Serial.println("B -");
    return;
  }
  Serial.print("B ");
  Serial.print((x - X_OFFSET_COUNTS) * X_MM_PER_COUNT, 1);
  Serial.print(",");
  Serial.println((y - Y_OFFSET_COUNTS) * Y_MM_PER_COUNT, 1);
}

// "W " and six whole numbers of 3 or 4 digits, one comma between them, nothing after: into us.
bool parseFrame(const char *s, int us[6]) {
  if (s[0] != 'W' || s[1] != ' ') {
    return false;
  }
  s += 2;
  for (int i = 0; i < 6; i++) {
    int digits = 0;
    long v = 0;
    while (*s >= '0' && *s <= '9') {
      v = v * 10 + (*s - '0');
      s++;
      if (++digits > 4) {
        return false;
      }
    }
    if (digits < 3) {
      return false;
    }
    us[i] = (int)v;
    if (i < 5) {
      if (*s != ',') {
        return false;
      }
      s++;
    }
  }
  return *s == 0;
}

void handleLine() {
  line[lineLen] = 0;
  if (lineFault) {
    Serial.print("E ");
    Serial.println(lineFault);
    return;
  }
  if (lineLen == 0) {  // an empty line ends a half line left by an earlier connection: nothing to say
    return;
  }
  if (line[0] == '?' && line[1] == 0) {
    reportHeld();
    return;
  }
  int us[6];
  if (!parseFrame(line, us)) {
    Serial.println("E expected W w0,w1,w2,w3,w4,w5 or ?");
    return;
  }
  for (int i = 0; i < 6; i++) {
    if (us[i] < SERVO_MIN_US || us[i] > SERVO_MAX_US) {
      Serial.println("E pulse outside the fence");
      return;
    }
  }
  writeServos(us);
}

void setup() {
  Serial.begin(115200);
  Wire.begin();
  Wire.setClock(400000);
  Wire.setWireTimeout(3000, true);  // a stuck bus ends a transaction with an error after 3 ms, not a hang
  releasePanel();
  while (!pcaAnswers()) {
    Serial.println("E no PCA9685 at I2C address 0x40: check its wiring and power");
    delay(1000);
  }
  pcaSetup();
  writeServos(heldUs);
  Serial.print("ready ");
  Serial.print(SERVO_MIN_US);
  Serial.print(",");
  Serial.println(SERVO_MAX_US);
}

void loop() {
  while (Serial.available()) {
    char c = Serial.read();
    if (c == '\n') {
      handleLine();
      lineLen = 0;
      lineFault = 0;
    } else if (c == 0) {
      lineFault = "NUL in line";
    } else if (c != '\r') {
      if (lineLen < sizeof(line) - 1) {
        line[lineLen++] = c;
      } else {
        lineFault = "line too long";
      }
    }
  }
  unsigned long now = micros();
  if (now - lastPanel >= PANEL_PERIOD_US) {
    lastPanel = now;
    reportPanel();
  }
}
