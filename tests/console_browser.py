#!/usr/bin/env python3
"""A real browser on the station (`ris console`): headless Chromium driven through WebDriver
(Debian's chromium and chromium-driver, Python selenium). It signs in as an operator, starts a
scan on the cell, watches its progress reach the verdict, opens the 3D view and picks points,
opens the print view; then signs in as a reader, who is offered no scan and whose forged
request is refused. Prints one JSON line with what it saw; the calling test checks it.

usage: console_browser.py URL CELL OPERATOR:PASSWORD READER:PASSWORD
"""
import json
import sys
import time

from selenium import webdriver
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.support import expected_conditions as EC
from selenium.webdriver.support.ui import Select, WebDriverWait


def browser():
    o = webdriver.ChromeOptions()
    o.binary_location = "/usr/bin/chromium"
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
              "--no-first-run", "--disable-background-networking",
              "--disable-component-update", "--disable-sync", "--window-size=1280,1800"):
        o.add_argument(a)
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=o)


def sign_in(d, url, user, password):
    d.get(url + "/login")
    d.find_element(By.NAME, "user").send_keys(user)
    d.find_element(By.NAME, "password").send_keys(password)
    d.find_element(By.CSS_SELECTOR, "form.login button").click()
    WebDriverWait(d, 30).until(EC.presence_of_element_located((By.CSS_SELECTOR, "header nav .who")))


def main():
    url, cell, op, rd = sys.argv[1], sys.argv[2], sys.argv[3].split(":", 1), sys.argv[4].split(":", 1)
    seen = {}
    d = browser()
    try:
        sign_in(d, url, *op)

        d.get(url + "/")
        end = time.time() + 60
        while not d.find_elements(By.CSS_SELECTOR, f'form.start option[value="{cell}"]'):
            if time.time() > end:
                raise SystemExit(f"cell {cell} is not offered for a scan")
            time.sleep(0.5)
            d.get(url + "/")
        seen["page_ready_ms"] = d.execute_script(
            "return performance.getEntriesByType('navigation')[0].domContentLoadedEventEnd")
        form = d.find_element(By.CSS_SELECTOR, "form.start")
        Select(form.find_element(By.NAME, "cell")).select_by_value(cell)
        form.find_element(By.NAME, "serial").send_keys("SN-BROWSER")
        form.find_element(By.NAME, "tag").send_keys("<script>alert(1)</script>")
        form.find_element(By.TAG_NAME, "button").click()
        # The scan's page: progress while it runs, then (reloaded when recorded) the verdict.
        WebDriverWait(d, 30).until(EC.url_contains(f"/cells/{cell}/scans/"))
        seen["scan_id"] = d.current_url.rstrip("/").rsplit("/", 1)[1]
        progress = set()
        end = time.time() + 180
        while time.time() < end:
            v = d.find_elements(By.ID, "verdict")
            if v:
                seen["verdict"] = v[0].text
                break
            for p in d.find_elements(By.ID, "progress"):
                try:
                    progress.add(p.text.split(":")[0])
                except Exception:
                    pass
            time.sleep(0.1)
        seen["progress"] = sorted(progress)
        seen["tag_text"] = any("<script>alert(1)</script>" in td.text
                               for td in d.find_elements(By.CSS_SELECTOR, "table.meta td"))
        try:
            d.switch_to.alert
            seen["alert"] = True
        except Exception:
            seen["alert"] = False
        # The 3D view: ready, then picks.
        canvas = WebDriverWait(d, 60).until(
            lambda d: d.find_element(By.ID, "view") if d.find_element(By.ID, "view").get_attribute("data-ready-ms") else False)
        seen["view_ready_ms"] = float(canvas.get_attribute("data-ready-ms"))
        seen["view_points"] = int(canvas.get_attribute("data-points"))
        picks = []
        w, h = canvas.size["width"], canvas.size["height"]
        for fx, fy in ((0.5, 0.5), (0.4, 0.45), (0.6, 0.55), (0.45, 0.6)):
            ActionChains(d).move_to_element_with_offset(canvas, int((fx - 0.5) * w), int((fy - 0.5) * h)).click().perform()
            pick = d.find_element(By.ID, "pick")
            if pick.get_attribute("data-index") is not None:
                picks.append({k: float(pick.get_attribute("data-" + k)) for k in ("x", "y", "z", "deviation")}
                             | {"text": pick.text})
        seen["picks"] = picks
        # Rotating redraws (the view is interactive).
        ActionChains(d).move_to_element(canvas).click_and_hold().move_by_offset(60, 20).release().perform()
        # The print view: navigation and controls hidden, the verdict kept.
        d.execute_cdp_cmd("Emulation.setEmulatedMedia", {"media": "print"})
        seen["print_nav_hidden"] = not d.find_element(By.CSS_SELECTOR, "header").is_displayed()
        seen["print_verdict_shown"] = d.find_element(By.ID, "verdict").is_displayed()
        pdf = d.execute_cdp_cmd("Page.printToPDF", {})
        seen["pdf_bytes"] = len(pdf.get("data", "")) * 3 // 4
        d.execute_cdp_cmd("Emulation.setEmulatedMedia", {"media": ""})
        # A reader: no scan offered, a forged request refused.
        d.find_element(By.CSS_SELECTOR, "form.inline button").click()
        sign_in(d, url, *rd)
        d.get(url + "/")
        WebDriverWait(d, 30).until(
            EC.presence_of_element_located((By.CSS_SELECTOR, f'section.cell[data-cell="{cell}"]')))
        seen["reader_start_forms"] = len(d.find_elements(By.CSS_SELECTOR, "form.start"))
        csrf = d.find_element(By.CSS_SELECTOR, "form.inline input[name=csrf]").get_attribute("value")
        status = d.execute_script(
            "return fetch(arguments[0], {method: 'POST', headers: {'Content-Type': 'application/x-www-form-urlencoded'},"
            " body: 'csrf=' + encodeURIComponent(arguments[1]) + '&cell=' + encodeURIComponent(arguments[2]) + '&mode=gray'}).then(r => r.status);",
            "/scan", csrf, cell)
        seen["reader_scan_status"] = status
    finally:
        d.quit()
    print(json.dumps(seen))


if __name__ == "__main__":
    main()
