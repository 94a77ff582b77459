/* Never flashed: this app exists so configuring it builds libmicroros.a. */
void app_main(void) {}
